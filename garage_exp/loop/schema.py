"""The schema of `python -m garage_exp.loop`'s config (conf/loop.yaml), registered in Hydra's ConfigStore."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from hydra.core.config_store import ConfigStore

from garage_exp import config  # noqa: F401 - the loop composes the experiment's config (its steps' checks)
from garage_exp.search.schema import SpaceConf
from garage_exp.tracking.schema import TrackingConf

# What an arm spends per round and training seed; every arm must spend the same (app.check_budgets).
BUDGET_KEYS = ("frames", "trials", "train_frames", "epochs", "imgsz", "replay_fraction")


@dataclass
class ArmConf:
    """One arm: its generator (the search's sampler) and what joins its suite. A budget key left null takes the
    loop's shared value; one set here must equal every other arm's (the loop refuses unequal budgets)."""

    sampler: str = "random"  # the search's sampler that finds the arm's scenarios (random | tpe | archive | ...)
    keep: str = "failures"  # failures: the hard-and-fair failures join the suite | all: every scenario (arm R)
    # The generator's own settings of its sampler's method (`search.archive.*` only, e.g.
    # search.archive.parents=curiosity): what it draws from (the space) and what it may spend (the budget keys)
    # stay every arm's.
    overrides: list[str] = field(default_factory=list)
    frames: Optional[int] = None
    trials: Optional[int] = None
    train_frames: Optional[int] = None
    epochs: Optional[int] = None
    imgsz: Optional[int] = None
    replay_fraction: Optional[float] = None


@dataclass
class CostConf:
    """The cost model's rates, measured on the machine the loop is sized for (docs/loop.md, "Budget"); the defaults
    are a shared 2-core CPU's (2026-11-28)."""

    search_s: float = 85.0  # per search command: imports, the model's load, the space's check, the analysis after
    command_s: float = 25.0  # per other child command (a sweep, a training, verify): start-up and imports
    render_s_per_frame: float = 1.0  # a trial's frame: render, ground truth, detection, its dataset files
    trial_overhead_s: float = 6.0  # per trial or job: composing, building and tearing down its scene
    frames_per_trial: float = 22.0  # a trial's frames, mean over the space at the loop's case.motion.step
    train_s_per_image_epoch: float = 0.22  # one training image for one epoch
    val_s_per_image: float = 0.15  # one validation frame, each epoch and once after
    detect_s_per_frame: float = 0.06  # scoring one held-out frame with one detector (evaluation)
    load_s: float = 8.0  # loading one detector for the evaluation
    verify_s: float = 10.0  # one detector in `python -m garage_exp.verify` on a real set: its load and its images
    # A space with requirements (space=wide) rejects draws before rendering and redraws them: the share of draws
    # accepted and the time one rejected draw takes (composing its scene and checking it).
    acceptance: float = 1.0
    reject_s: float = 0.0
    # The protocol suite's jobs (shipped cases with motion, not the space's scenarios): a job's seconds and frames;
    # None: a trial's (the loop's space is the protocol's kind of scenario).
    protocol_job_s: Optional[float] = None
    check_s: float = 0.0  # the loop's up-front check of every step (check.py): seconds on a wide space, else few
    # A held-out trial when it differs from a search's (the wide loop's held-out study asks its trials from 4,096
    # enqueued Sobol' points, and measured 2.1 s a trial against the generators' 0.7 s); None: a search's trial.
    heldout_trial_s: Optional[float] = None
    protocol_frames_per_job: Optional[float] = None


@dataclass
class GaragesConf:
    """On a space of generated garages (`plan=generated`, `space=wide`; loop/garages.py): the generator seeds the
    training searches draw from, the disjoint range the held-out sample draws from, and the layout families only
    the held-out sample has."""

    train_seeds: list[int] = field(default_factory=lambda: [0, 499_999])
    heldout_seeds: list[int] = field(default_factory=lambda: [500_000, 999_999])
    heldout_families: list[str] = field(default_factory=lambda: ["spine"])


@dataclass
class PowerConf:
    """The power estimate printed with the cost (loop/stats.py, scenarios_for): from a pilot's failure rate, how
    many held-out scenarios per detector detect a relative difference in failure rate at alpha (Holm over every
    comparison the report makes: its first step tests at alpha / comparisons), with this power."""

    pilot_rate: float = 0.3  # D0's failures per scenario on a pilot of the loop's held-out sample
    relative: float = 0.2  # the difference to detect: 20 % fewer failures
    alpha: float = 0.05
    power: float = 0.8
    scenario_share: float = 1.0  # of the held-out trials, those that render a scenario (else: actors overlap)
    # A pilot's share of held-out scenarios two arms' detectors disagreed on (a run's power.json,
    # discordant_share): the estimate then adds McNemar's scenarios (stats.scenarios_for_paired); None: not measured.
    pilot_discordant: Optional[float] = None


@dataclass
class ForgettingConf:
    """Issue 50's goals for what must not be forgotten (loop/forgetting.py): each arm's recall after the last round
    may fall below D0's by at most this much, on each protocol suite and on each real-photo set."""

    protocol_recall: float = 0.02
    photo_recall: float = 0.05


@dataclass
class ReplayPoolConf:
    """One more source of replay frames (never validation): a QMC study on the training garages, its space the
    loop's with `params` (the search's override grammar) overriding the space's entries of the same key, e.g. a
    pool whose targets are all people (`case.actors.target.type=choice(child,adult,crouching)`)."""

    trials: int = 0
    params: list[str] = field(default_factory=list)


@dataclass
class LoopConf:
    dir: str = "outputs/loop/default"  # every study, dataset, training and result of the loop
    # A name for another run of the arms (other replay, epochs ...) in the same dir, sharing its base data, D0 and
    # held-out suites; its studies, trainings and results get this suffix. Empty: the first run's names.
    variant: str = ""
    # The declared scenario space, shared by every study: a shipped space (conf/space/NAME.yaml, `space=wide`;
    # the loop's own: `space: loop`), its `params` in the search's override grammar (docs/search.md). searched()
    # says how the loop's searches are given it.
    space: SpaceConf = field(default_factory=lambda: SpaceConf(name="loop", params=[
        "case=choice('1','2','3',pedestrian)", "light=choice(bright,clear,moderate,dim)", "seed=int(interval(0,9999))"]))
    fixed: list[str] = field(default_factory=lambda: ["case.motion.step=2.0"])  # set on every job
    train_plans: list[str] = field(default_factory=lambda: ["research", "realistic"])
    eval_plan: str = "obstacles"  # no training frame comes from it
    # On a space of generated garages the plans above are not used: these seeds and families are (loop/garages.py).
    garages: GaragesConf = field(default_factory=GaragesConf)
    # D0: a .pt detector (the COCO-pretrained yolo11n rebuilt from INT8), or a model YAML trained from scratch on
    # the base data (base_epochs, base_lr0).
    base: str = "../shared/models/yolo11n_fp32_from_int8.pt"
    base_epochs: int = 25
    base_lr0: float = 0.002
    bn_calibrate: int = 64  # each fine-tuning calibrates its base's BatchNorms on this many of its frames (0: not)
    base_trials: int = 16  # QMC scenarios on the training plans: the replay pool and the validation scenarios
    # More replay than the base data's training scenarios hold (docs/loop.md, "Not forgetting"): each entry a study
    # on the training garages (`replay_<name>`) whose scenarios join every fine-tuning's replay pool.
    replay_pool: dict[str, ReplayPoolConf] = field(default_factory=dict)
    optimizer: str = "AdamW"
    lr0: float = 0.0005  # the arms' fine-tuning
    # The first N layers of every arm's fine-tuning kept frozen (ultralytics' `freeze`; yolo11n: 0-9 its backbone,
    # 23 its Detect head): what a fine-tuning may forget of D0's COCO training (docs/loop.md, "Not forgetting").
    freeze: int = 0
    # The detectors the loop delivers (each round's, scored on every suite) as their weights interpolated toward
    # D0's: this share the fine-tuned weights', the rest D0's (WiSE-FT, train/wise.py); 1: as trained. The rounds
    # train and search as without it, so `variant=NAME wise=A` scores NAME's training again at once.
    wise: float = 1.0
    warmup_bias_lr: float = 0.0  # the fine-tunings' bias warm-up start (ultralytics' 0.1 shakes a pretrained head)
    batch: int = 16
    rounds: int = 2
    arms: dict[str, ArmConf] = field(default_factory=lambda: {
        "R": ArmConf("random", "all"), "T": ArmConf("tpe"), "Q": ArmConf("archive")})
    # Each arm's budget per round and training seed (an arm may repeat them, never change them).
    # its generator's budget: frames rendered (and scored by the arm's detector) per round and seed; the search
    # stops asking for scenarios once its trials rendered this many (search.frames), so arms are compared at equal
    # rendering cost (a trial's frames vary with its case: 8-26 at step 4). 0: by trials alone.
    frames: int = 0
    trials: int = 8  # its generator's trials: the cap under a frame budget, else the budget itself
    startup: int = 10  # the generators' search.startup: random trials before TPE's (or GP's) model guides
    train_frames: int = 64  # frames of its suite it is fine-tuned on
    epochs: int = 3
    imgsz: int = 320
    replay_fraction: float = 1.0  # replay frames of the base data per training frame
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2, 3, 4])
    val_fraction: float = 0.25  # of the base scenarios, held out to validate every training
    heldout_trials: int = 48  # the failure-rate sample: scenarios of eval_plan, quasi-random
    heldout_seed: int = 0
    heldout_method: str = "sobol"  # sobol | halton
    # The protocol suite: each entry one sweep of the main command (its overrides), rendered once, every detector
    # scored on its fair frames.
    protocol: dict[str, list[str]] = field(default_factory=lambda: {
        "cpnco": ["+experiment=cpnco"], "cpra": ["+experiment=cpra"], "crossing": ["case=crossing", "light=bright,dim"],
        "crouch": ["case=crouch", "light=bright,dim"]})
    protocol_fixed: list[str] = field(default_factory=lambda: ["case.motion.step=2.0"])
    photos: bool = True  # the real-photo suite: the two hand-labelled photos ultralytics ships, through verify
    real_sets: list[str] = field(default_factory=list)  # more labelled real sets (verify's data=), e.g. your own
    hard_below: float = 0.4  # a failure: a fair scenario whose mean confidence is below this
    threshold: float = 0.5  # composite confidence counted as detected
    estimate: bool = False  # print the cost model's estimate of this config and stop
    power: PowerConf = field(default_factory=PowerConf)
    forgetting: ForgettingConf = field(default_factory=ForgettingConf)
    cost: CostConf = field(default_factory=CostConf)
    tracking: TrackingConf = field(default_factory=lambda: TrackingConf(experiment="garage_loop"))


def register() -> None:
    ConfigStore.instance().store(name="loop_schema", node=LoopConf)


def searched(cfg) -> list[str]:
    """The loop's space as a search command's overrides: `space=NAME` while its params are its file's or empty (the
    search then takes the file's requirements, cells and one-shot case too), else the params alone (`space.params=[...]`
    on the loop's command line replaces the file's list, as the loop's space list always did)."""
    from omegaconf import OmegaConf

    from garage_exp.core.paths import PROJECT_ROOT

    name, params = str(cfg.space.name), [str(p) for p in cfg.space.params]
    path = PROJECT_ROOT / "conf" / "space" / f"{name}.yaml"
    # no params of its own: the named file's (a config such as conf/loop_wide.yaml names its space so)
    if path.is_file() and (not params or [str(p) for p in OmegaConf.load(path).get("params") or []] == params):
        return [f"space={name}"]
    return params


def space_config(argv: list[str]) -> list[str]:
    """`space=NAME` with no config named: the loop's config sized for that space, conf/loop_NAME.yaml, when one is
    shipped (`space=wide`: conf/loop_wide.yaml, whose budgets fit one-shot scenarios; conf/loop.yaml's frame
    budget is for the loop space's scenarios of many frames), else the argv as given."""
    from garage_exp.core.paths import PROJECT_ROOT

    named = [a.split("=", 1)[1] for a in argv if a.startswith("space=")]
    if not named or any(a.startswith(("--config-name", "-cn", "--config-dir", "-cd")) for a in argv):
        return argv
    config = f"loop_{named[-1]}"
    return ["--config-name", config, *argv] if (PROJECT_ROOT / "conf" / f"{config}.yaml").is_file() else argv


def space_by_name(argv: list[str]) -> list[str]:
    """`space=NAME` on the loop's command line as the space's name and params (`space.name=NAME`,
    `space.params=[...]`): the loop reads a shipped space's list of overrides, not the whole level, whose defaults
    list may pick groups the loop's own config has not (the wide space picks its one-shot `case`). A name with no
    file is left as written, for Hydra to refuse in its own words."""
    from omegaconf import OmegaConf

    from garage_exp.core.paths import PROJECT_ROOT

    out = []
    for arg in argv:
        name = arg.split("=", 1)[1] if arg.startswith("space=") else None
        path = PROJECT_ROOT / "conf" / "space" / f"{name}.yaml"
        if name is None or not path.is_file():
            out.append(arg)
            continue
        params = [str(p) for p in OmegaConf.load(path).get("params") or []]
        out += [f"space.name={name}", "space.params=[" + ",".join(f'"{p}"' for p in params) + "]"]
    return out


def space_file(cfg):
    """The shipped space's file (conf/space/NAME.yaml) when the loop's searches are given it by name (searched()),
    else None: its `require` and `descriptors` then hold for every search of the loop."""
    from omegaconf import OmegaConf

    from garage_exp.core.paths import PROJECT_ROOT

    named = [e.split("=", 1)[1] for e in searched(cfg) if e.startswith("space=")]
    path = PROJECT_ROOT / "conf" / "space" / f"{named[0]}.yaml" if named else None
    return OmegaConf.load(path) if path and path.is_file() else None


def space_descriptors(cfg) -> list:
    """The archive's cells the shipped space names (its file's `descriptors: NAME`, search/schema.py's
    DESCRIPTOR_SETS), which its searches then use; [] for a space that names none."""
    from garage_exp.search.schema import DESCRIPTOR_SETS

    name = (space_file(cfg) or {}).get("descriptors")
    return DESCRIPTOR_SETS[name]() if name in DESCRIPTOR_SETS else []
