"""The loop's steps as the project's own commands, run as child processes, and what their studies left.

A search with dataset=true leaves each trial's frames, labelled, in its job dir (`<sweep>/<k>/dataset`): a trial
is a scenario, so a study's trials are training or evaluation data as they are, without rendering them again.
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from omegaconf import DictConfig

from garage_exp.core.exits import wait_child
from garage_exp.loop.schema import searched


@dataclass
class Trial:
    study: str
    number: int
    state: str  # COMPLETE | PRUNED (no fair frame) | FAIL
    difficulty: float | None  # 1 - mean confidence over the fair frames (COMPLETE only)
    output_dir: Path | None
    frames: int = 0  # frames the trial rendered (its job's count)
    params: dict | None = None  # its searched values (a held-out scenario's garage family, for the report)
    rejected: bool = False  # a draw the space's requirements rejected before rendering (PRUNED, redrawn)
    infeasible: bool = False  # a draw whose actors overlap: PRUNED, nothing rendered (a trial of the budget)

    @property
    def ran(self) -> bool:
        """A scenario that counts: finished and not a rejected draw (which takes no place in any budget)."""
        return self.state in ("COMPLETE", "PRUNED", "FAIL") and not self.rejected

    @property
    def dataset(self) -> Path | None:
        if self.output_dir is None:
            return None
        d = self.output_dir / "dataset"
        return d if (d / "data.yaml").is_file() else None


def storage(cfg: DictConfig) -> str:
    return f"sqlite:///{Path(cfg.dir) / 'optuna.db'}"


def search_command(cfg: DictConfig, study: str, garage: list[str], trials: int, sampler: str, seed: int,
                   models: list[str] | None = None, startup: int | None = None, frames: int = 0,
                   extra: list[str] = ()) -> list[str]:
    """`python -m garage_exp -m hydra/sweeper=search ...` over the loop's space on the garages `garage` says
    (overrides: loop/garages.py's train() or heldout()), each trial with its dataset; scored by `models` (None:
    the shipped detectors)."""
    cmd = [sys.executable, "-m", "garage_exp", "-m", "hydra/sweeper=search", f"search.trials={trials}",
           f"search.sampler={sampler}", f"search.seed={seed}", f"search.study={study}",
           f"search.storage={storage(cfg)}", *with_garage(cfg, garage), *cfg.fixed, "dataset=true",
           f"detector.threshold={cfg.threshold}", f"tracking.uri={cfg.tracking.uri}",
           f"tracking.experiment={cfg.tracking.experiment}", f"hydra.sweep.dir={Path(cfg.dir) / 'studies' / study}"]
    if models:
        cmd += [f"detector.models=[{','.join(models)}]", f"detector.imgsz={cfg.imgsz}"]
    if startup is not None:
        cmd.append(f"search.startup={startup}")
    if frames:
        cmd.append(f"search.frames={frames}")  # the generator's budget of rendered frames; `trials` its cap
    return cmd + list(extra)  # an arm's own settings of its sampler (arms.ARM.overrides): none, before they existed


def train_command(cfg: DictConfig, name: str, out: Path, data: list[Path], val: list[Path], base: str, epochs: int,
                  seed: int, lr0: float, replay: list[Path] = (), study: str = "", imgsz: int | None = None,
                  replay_fraction: float | None = None, calibrate: bool = False, freeze: int = 0) -> list[str]:
    cmd = [sys.executable, "-m", "garage_exp.train", f"data=[{','.join(map(str, data))}]",
           f"val=[{','.join(map(str, val))}]", f"base={base}", f"epochs={epochs}", f"imgsz={imgsz or cfg.imgsz}",
           f"batch={cfg.batch}", f"seed={seed}", f"optimizer={cfg.optimizer}", f"lr0={lr0}", f"name={name}",
           f"study={study}",
           f"tracking.uri={cfg.tracking.uri}", f"tracking.experiment={cfg.tracking.experiment}",
           f"hydra.run.dir={out}"]
    if replay:
        fraction = cfg.replay_fraction if replay_fraction is None else replay_fraction
        cmd += [f"replay=[{','.join(map(str, replay))}]", f"replay_fraction={fraction}"]
    if calibrate and int(cfg.bn_calibrate):
        cmd.append(f"bn_calibrate={int(cfg.bn_calibrate)}")
    if calibrate:  # fine-tuning the pretrained D0 and its descendants: the biases warm up from 0, not 0.1
        cmd.append(f"warmup_bias_lr={cfg.warmup_bias_lr}")
    if freeze:  # only when set: a loop of before (freeze 0) resumes with the same commands
        cmd.append(f"freeze={int(freeze)}")
    return cmd


def with_garage(cfg: DictConfig, garage: list[str]) -> list[str]:
    """The garage's overrides, then the loop's space less the entries whose key they set (a space given as its
    params lists `plan.seed` itself; a shipped space's `space=NAME` yields its keys to the command's own)."""
    keys = {g.split("=", 1)[0] for g in garage}
    return [*garage, *(e for e in searched(cfg) if e.split("=", 1)[0] not in keys)]


def sweep_command(cfg: DictConfig, out: Path, overrides: list[str]) -> list[str]:
    """`python -m garage_exp -m OVERRIDES dataset=true`: a plain sweep (a protocol's jobs), each job's frames
    labelled in its dir (`out/<k>/dataset`), scored by the shipped detectors (the loop scores its own later)."""
    return [sys.executable, "-m", "garage_exp", "-m", *overrides, "dataset=true",
            f"detector.threshold={cfg.threshold}", f"tracking.uri={cfg.tracking.uri}",
            f"tracking.experiment={cfg.tracking.experiment}", f"hydra.sweep.dir={out}"]


def verify_command(cfg: DictConfig, out: Path, data: str, weights: list[str]) -> list[str]:
    """`python -m garage_exp.verify` of detectors (their .pt files, each scored on its own, at the loop's image
    size) on a labelled real set; the shipped photos' "pedestrian" labels are people."""
    from garage_exp.results.photos import LABEL_MAP

    return [sys.executable, "-m", "garage_exp.verify", f"data={data}", *LABEL_MAP,
            f"detector.models=[{','.join(weights)}]",
            f"detector.imgsz={cfg.imgsz}", f"detector.threshold={cfg.threshold}", f"tracking.uri={cfg.tracking.uri}",
            f"tracking.experiment={cfg.tracking.experiment}", f"hydra.run.dir={out}"]


def jobs(name: str, out: Path) -> list[Trial]:
    """A sweep's jobs as trials (number: the job's index), those that left a dataset, in order."""
    dirs = sorted((d for d in out.iterdir() if d.is_dir() and d.name.isdigit()), key=lambda d: int(d.name))
    return [Trial(name, int(d.name), "COMPLETE", None, d) for d in dirs
            if (d / "dataset" / "data.yaml").is_file() and (d / "frames.csv").is_file()]


def run(cmd: list[str], log: Path) -> None:
    """Run a step, its output (progress bars included) appended to `log`; a failed step stops the loop."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") as fh:
        fh.write("\n$ " + " ".join(cmd) + "\n")
        fh.flush()
        code = wait_child(cmd, stdout=fh, stderr=subprocess.STDOUT)
    if code not in (0, 1):  # 1: a study with failed trials (a case a plan cannot hold) still has its others
        raise RuntimeError(f"step failed with exit code {code}: {' '.join(cmd[2:6])} ... (log: {log})")


def trials(cfg: DictConfig, study: str) -> list[Trial]:
    """Every trial of a study in the loop's storage, in order."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    s = optuna.load_study(study_name=study, storage=storage(cfg))
    out = []
    for t in s.get_trials(deepcopy=False):
        d = t.user_attrs.get("output_dir")
        out.append(Trial(study, t.number, t.state.name, t.values[0] if t.values else None,
                         Path(d) if d else None, int(t.user_attrs.get("frames") or 0), dict(t.params),
                         "rejected" in t.user_attrs, bool(t.user_attrs.get("infeasible"))))
    return out


def study_done(cfg: DictConfig, study: str, n: int, frames: int = 0) -> bool:
    """Whether the study holds its n trials or, under a frame budget, rendered its frames."""
    try:
        # WAITING (enqueued, not run yet) and RUNNING trials are not done
        done = [t for t in trials(cfg, study) if t.ran]  # a rejected draw was redrawn: it is no trial
    except KeyError:  # no such study yet
        return False
    return len(done) >= n or (frames > 0 and sum(t.frames for t in done) >= frames)


def digests(paths: list[Path]) -> list[str]:
    """`input:PATH=sha256:...` for each file a step reads, and for a data.yaml the .txt image list beside it (the
    same path may hold another split or another draw); a models:/ name or a YAML ultralytics ships is no file."""
    out = []
    for path in paths:
        for f in (path, path.with_suffix(".txt")) if path.suffix in (".yaml", ".yml") else (path,):
            if f.is_file():
                out.append(f"input:{f}=sha256:{hashlib.sha256(f.read_bytes()).hexdigest()[:16]}")
    return out


def changes(old: list[str], new: list[str], most: int = 3) -> str:
    """What differs between two steps' inputs, by key: `search.trials=4 -> 5`, `input data/hard.yaml changed`."""
    def by_key(items):
        return dict(item.split("=", 1) if "=" in item else (item, "") for item in items)

    a, b = by_key(old), by_key(new)
    said = []
    for key in [k for k in {**a, **b} if a.get(k) != b.get(k)]:
        if key.startswith("input:"):
            said.append(f"{Path(key[6:]).name} {'changed' if key in a and key in b else 'differs'}")
        else:
            said.append(f"{key}={a.get(key, '(none)')} -> {b.get(key, '(none)')}")
    return ", ".join(said[:most]) + (f", ... {len(said) - most} more" if len(said) > most else "")
