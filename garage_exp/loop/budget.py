"""The arms' data, with equal budgets: in each round an arm's generator (a search of the same number of trials over
the same space) finds scenarios; those that join its suite (its hard-and-fair failures, or every scenario for the
random arm) add to the suites of the rounds before, and the arm is fine-tuned on exactly `train_frames` frames of
its suite, with the same replay fraction, epochs and image size as every other arm; the trainings' own counts are
compared afterwards (`assert_equal_budget`)."""

from __future__ import annotations

import random
from pathlib import Path

import yaml

from garage_exp.core.errors import JobFault
from garage_exp.loop.steps import Trial


def arm_budget(cfg, arm: str) -> dict:
    """An arm's budget per round and seed (the loop's config): its own keys where set, else the loop's shared ones."""
    from garage_exp.loop.schema import BUDGET_KEYS as ARM_KEYS

    own = cfg.arms[arm]
    return {k: (own[k] if own.get(k) is not None else cfg[k]) for k in ARM_KEYS}


def failures(trials: list[Trial], hard_below: float) -> tuple[int, int]:
    """(hard-and-fair failures, trials): a failure is a COMPLETE trial (some fair frame) whose mean confidence over
    its fair frames is below `hard_below`; every trial that ran counts in the denominator."""
    ran = [t for t in trials if t.ran]
    hard = [t for t in ran if t.state == "COMPLETE" and 1.0 - t.difficulty < hard_below]
    return len(hard), len(ran)


def joining(found: list[Trial], keep: str, hard_below: float) -> list[Trial]:
    """The trials of a round's search that join the arm's suite: its hard-and-fair failures (keep=failures), or
    every trial that left a dataset (keep=all: the random arm's scenarios)."""
    with_data = [t for t in found if t.dataset is not None]
    if keep == "all":
        return with_data
    return [t for t in with_data if t.state == "COMPLETE" and 1.0 - t.difficulty < hard_below]


def failure_frames(frames: list[Path], trials: list[Trial], hard_below: float) -> int:
    """How many of a fine-tuning's frames show a hard-and-fair failure of the detector that rendered them (the
    arm's detector of that round): what makes a targeted arm's data targeted. Random scenarios hold failures too,
    as many as the space's failure rate makes them (R's half of its frames where D0 fails half the space), so the
    two arms' shares say how differently they train (docs/loop.md)."""
    failed = {t.dataset for t in trials if t.dataset is not None and t.state == "COMPLETE"
              and 1.0 - t.difficulty < hard_below}
    return sum(1 for f in frames if f.parent.parent in failed)


def rendered(found: list[Trial]) -> int:
    """Frames a search rendered (the generator's cost), from each trial's own count."""
    return sum(t.frames for t in found)


def round_frames(suite: list[Trial], found: list[Trial], n: int, seed: int) -> tuple[list[Path], int]:
    """(exactly n frames to fine-tune on, how many of them topped the suite up). n frames are drawn at random
    (seeded) from the suite's frames; a suite holding fewer is used whole and topped up with frames of this round's
    other scenarios, hardest first (a generator that found few failures still spends its arm's budget, on the
    nearest misses). ValueError when even that is short: raise `trials` or lower `train_frames`."""
    pool = images([t.dataset for t in suite])
    if len(pool) >= n:
        return draw_frames(pool, n, seed), 0
    members = {t.dataset for t in suite}
    rest = sorted((t for t in found if t.dataset is not None and t.dataset not in members),
                  key=lambda t: (t.difficulty is None, -(t.difficulty or 0.0), t.number))
    extra = [f for t in rest for f in images([t.dataset])][:n - len(pool)]
    if len(pool) + len(extra) < n:
        raise ValueError(f"the suite and this round's scenarios hold {len(pool) + len(extra)} frames, fewer than "
                         f"train_frames={n}: raise trials or lower train_frames")
    return sorted(pool) + extra, len(extra)


def images(datasets: list[Path]) -> list[Path]:
    return sorted(p for d in datasets for p in (d / "images").iterdir() if p.suffix == ".png")


def draw_frames(pool: list[Path], n: int, seed: int) -> list[Path]:
    """n frames drawn at random (seeded) from the pool; ValueError when it holds fewer."""
    if n > len(pool):
        raise ValueError(f"the pool holds {len(pool)} frames, fewer than the {n} asked")
    return sorted(random.Random(seed).sample(sorted(pool), n))


def write_list(path: Path, frames: list[Path], names: dict[int, str]) -> Path:
    """A YOLO data.yaml over exactly these images (a .txt list beside it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    listing = path.with_suffix(".txt")
    listing.write_text("".join(f"{f}\n" for f in frames))
    path.write_text(yaml.safe_dump({"path": str(path.parent), "train": str(listing), "names": names},
                                   sort_keys=False))
    return path


def write_dirs(path: Path, datasets: list[Path], names: dict[int, str]) -> Path:
    """A YOLO data.yaml over whole datasets (each an images/ folder)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({"path": str(path.parent), "train": [str(d / "images") for d in datasets],
                                    "names": names}, sort_keys=False))
    return path


BUDGET_KEYS = ("train_frames", "replay_frames", "val_frames", "epochs", "imgsz")


def assert_equal_budget(trained: dict[str, dict]) -> None:
    """The arms' trainings of one round and seed (their result.json, by arm) read as many frames, for as many
    epochs, at one image size."""
    arms = list(trained)
    first = trained[arms[0]]
    for arm in arms[1:]:
        unequal = {k: (first.get(k), trained[arm].get(k)) for k in BUDGET_KEYS if first.get(k) != trained[arm].get(k)}
        if unequal:
            raise AssertionError(f"unequal budgets between the arms ({arms[0]}, {arm}): {unequal}")


def check_replay(cfg, pool: list[Path], kept: str) -> None:
    """The base data's training scenarios hold every arm's replay (train_frames x replay_fraction frames), else a
    JobFault (one line, exit 1) before a fine-tuning: on a space whose draws are often infeasible
    (one-shot scenarios whose actors overlap render nothing), base_trials scenarios hold fewer frames than trials,
    and the fine-tuning's own refusal would stop the loop with a traceback."""
    need = max(round(float(arm_budget(cfg, arm)["replay_fraction"]) * int(arm_budget(cfg, arm)["train_frames"]))
               for arm in cfg.arms)
    have = len(images(pool))
    if have < need:
        holder = "the base data and its replay pools hold" if cfg.get("replay_pool") else "the base data holds"
        raise JobFault(f"{holder} {have} replay frames outside its validation scenarios, fewer than the "
                       f"{need} a fine-tuning replays (train_frames x replay_fraction): raise base_trials (in another "
                       f"dir), add a replay_pool or lower replay_fraction; the steps done so far are kept under {kept}")


def check_spent(arm: str, found: list[Trial], frames: int, where: str, kept: str) -> None:
    """The arm's generator rendered its budget of `frames` (nothing to check without one: the arms then spend equal
    trials). A JobFault (one line, exit 1) when it stopped short at its cap of trials: a shortfall the loop's check
    could not see before rendering (`check.check_steps` refuses a cap that no trials of the space could fill), found
    once the trials rendered fewer frames than the most a trial can; what the loop made so far is kept (`kept`)."""
    spent = rendered(found)
    if frames > 0 and spent < frames:
        raise JobFault(f"{where}: arm {arm}'s generator rendered {spent} frames in its {len(found)} trials, short of "
                       f"its budget of {frames}: raise trials (the generators' cap; in another dir or with "
                       f"variant=NAME, since a step is not rerun with other inputs); the steps done so far are kept "
                       f"under {kept}")


def assert_equal_frames(generated: dict[str, list[Trial]], frames: int, where: str, kept: str = "its dir") -> None:
    """The arms' generators of one round and seed (their trials, by arm) each rendered their budget of frames:
    at least `frames` (`check_spent`), and less than one of its own trials' frames more (the trial that crossed the
    budget ends); nothing to check without a frame budget (the arms then spend equal trials)."""
    if frames <= 0:
        return
    for arm, found in generated.items():
        check_spent(arm, found, frames, where, kept)
        spent = rendered(found)
        if spent - max(t.frames for t in found) >= frames:
            raise AssertionError(f"arm {arm}'s generator rendered {spent} frames, over its budget of {frames} by more "
                                 "than one of its trials: the search did not stop at its budget")
