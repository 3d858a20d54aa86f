"""What the loop's steps would refuse, checked before its first step (issue 47, item 2): a bad space, an unknown
`eval_plan`, a protocol's typo or an unreachable frame budget is one line and exit 2 with nothing written, not a
step failing minutes (or hours) into the loop with its studies half made.

Each step is checked as its own command checks it, in this process: a search's settings, space and models as the
search's sweeper does (`search.sweep.check`: every choice and each interval's ends composed and preflighted), a
protocol's every job as the main command's sweep does (`run.sweep_check.check_sweep`). Steps whose inputs do not
exist yet (the trainings' data, the later rounds' detectors) are checked by the loop's own settings
(`app.check_loop`) and by their commands when they run.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from omegaconf import DictConfig

from garage_exp.core.errors import GarageError
from garage_exp.loop import steps


def check_steps(cfg: DictConfig) -> None:
    """GarageError (one line naming the loop's key and its step) for the first step the loop would see refused."""
    from garage_exp.loop.budget import arm_budget

    base_pt = str(Path(str(cfg.base)).expanduser().absolute()) if str(cfg.base).endswith(".pt") else None
    models = [base_pt] if base_pt else None  # D0 trained from a model YAML is not there yet: the shipped detectors
    from garage_exp.loop import garages

    plans = garages.train(cfg)
    # (step, study, garage overrides, trials, sampler, seed, models, startup, frames, extra): as run_loop asks
    studies = [("base data", "base", plans, int(cfg.base_trials), "qmc", 0, models, None, 0, ()),
               ("held-out sample", "heldout", garages.heldout(cfg), int(cfg.heldout_trials), "random", 0, models,
                None, 0, ())]
    from garage_exp.loop import replay

    studies += [(p.step, p.study, p.overrides, p.trials, "qmc", p.seed, models, None, 0, ())
                for p in replay.pools(cfg, plans)]
    for arm in cfg.arms:  # round 1's generators: the later rounds differ only in their detector and search seed
        b = arm_budget(cfg, arm)
        studies.append((f"arm {arm}'s generator", f"gen_{arm}", plans, int(b["trials"]), cfg.arms[arm].sampler,
                        1000 + int(cfg.seeds[0]), models, int(cfg.startup), int(b["frames"]),
                        tuple(cfg.arms[arm].get("overrides") or ())))
    searches = [(s[0], steps.search_command(cfg, *s[1:])[4:], (tuple(s[2]), tuple(s[6] or ())), s[3], s[8])
                for s in studies]
    protocols = [(f"protocol {name}", steps.sweep_command(
        cfg, Path(str(cfg.dir)) / "studies" / f"protocol_{name}", [*overrides, *cfg.protocol_fixed])[4:])
        for name, overrides in cfg.protocol.items()]
    # First what composing alone refuses (an unknown plan or level, a key the schema lacks: a second each), then
    # each step's full check (its jobs preflighted, its models loaded: seconds).
    for step, overrides in [s[:2] for s in searches] + protocols:
        _checked(cfg, step, lambda o=overrides: _compose(_loader(), o))
    spaces = {}  # (plans, models) -> the space as checked: the searches on them share the space and its jobs
    for step, overrides, key, trials, frames in searches:
        if key not in spaces:
            spaces[key] = _checked(cfg, step, lambda o=overrides: _search(o))
        else:  # the same space on the same plans and models: only the search's own settings differ
            _checked(cfg, step, lambda o=overrides: _search_settings(o))
        fewest, most = spaces[key].fewest_frames, spaces[key].most_frames
        if frames and trials * fewest < frames:  # a sampler may pick the shortest scenario every time
            raise GarageError(
                f"{step}'s cap of {trials} trials may not reach its budget of {frames} frames: a trial renders "
                f"{fewest} to {most} frames (the space's points at {' '.join(cfg.fixed) or 'their step'}); raise "
                f"trials to at least {math.ceil(frames / max(fewest, 1))} or lower frames (frames=0: the trials are "
                "the budget)", "trials")
    for step, overrides in protocols:
        _checked(cfg, step, lambda o=overrides: _sweep(o))


def _search(overrides: list[str]):
    """The search command's check, as its sweeper runs it before its first trial; its space."""
    from garage_exp.search import sweep

    loader = _loader()
    return sweep.check(_compose(loader, overrides), loader)


def _search_settings(overrides: list[str]) -> None:
    """The search's own settings (sampler, trials, frames, startup), as its sweeper checks them first."""
    from garage_exp.search.study import check_search

    check_search(_compose(_loader(), overrides).search)


def _sweep(overrides: list[str]) -> None:
    """A plain sweep's check, as the main command's sweep callback runs it before its first job."""
    from garage_exp.run.sweep_check import check_sweep

    check_sweep(_compose(_loader(), overrides))


def _loader():
    from hydra.core.global_hydra import GlobalHydra

    return GlobalHydra.instance().config_loader()  # the loop's own Hydra: the same conf/, its config the main one


def _compose(loader, overrides: list[str]) -> DictConfig:
    from hydra.types import RunMode

    from garage_exp.core.overrides import quote_numeric_choices

    return loader.load_configuration("config", quote_numeric_choices(overrides), RunMode.MULTIRUN)


def _checked(cfg: DictConfig, step: str, check):
    """check()'s result; its refusal (ours or Hydra's) as one GarageError naming the loop's key it comes from."""
    from garage_exp.core.exits import input_error

    try:
        return check()
    except Exception as exc:  # noqa: BLE001 - an input error becomes one line; anything else is a bug
        text = input_error(exc)
        if text is None:
            raise
        raise GarageError(f"{text} (the loop's {step})", blame(cfg, text, step)) from None


def blame(cfg: DictConfig, text: str, step: str) -> str:
    """The loop's key whose value the refusal names: an override of `fixed`, `space` or a protocol as written (a
    searched key also as the search names its probed values), `eval_plan`, `train_plans`; else the step."""
    protocol = step.split(" ", 1)[1] if step.startswith("protocol ") else None
    sources = ([("protocol_fixed", cfg.protocol_fixed), (f"protocol.{protocol}", cfg.protocol[protocol])]
               if protocol else [("fixed", cfg.fixed), ("space.params", cfg.space.params)])
    for key, overrides in sources:
        if any(str(o) in text for o in overrides):
            return key
    for key, overrides in sources:  # a dotted key the refusal names (`detector.models /abs/path: ...`)
        if any("." in dotted(o) and re.search(rf"(^|[\s:]){re.escape(dotted(o))}[\s=:]", text) for o in overrides):
            return key
    if protocol:
        return f"protocol.{protocol}"
    if any(f"search space {dotted(o)}=" in text for o in cfg.space.params):
        return "space.params"
    if step == "held-out sample" and str(cfg.eval_plan) in text:
        return "eval_plan"
    if any(str(p) in text for p in cfg.train_plans):
        return "train_plans"
    return step


def dotted(override) -> str:
    """An override's key as written (`case.motion.step` of `case.motion.step=4.0`, `+` and `~` dropped)."""
    return str(override).split("=", 1)[0].lstrip("+~")

