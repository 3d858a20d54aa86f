"""The arms' data, with equal budgets: H's frames are its hard scenarios' frames, R's exactly as many frames drawn at
random from scenarios of the same space; both get the same replay (same base pool, fraction and seed) and the same
epochs and image size, and the trainings' own counts are compared afterwards (`assert_equal_budget`)."""

from __future__ import annotations

import random
from pathlib import Path

import yaml

from garage_exp.loop.steps import Trial


def hardest(trials: list[Trial], k: int) -> list[Trial]:
    """The k hardest fairly visible trials (COMPLETE, highest difficulty first) that left a dataset."""
    done = [t for t in trials if t.state == "COMPLETE" and t.dataset is not None]
    return sorted(done, key=lambda t: (-t.difficulty, t.number))[:k]


def failures(trials: list[Trial], hard_below: float) -> tuple[int, int]:
    """(hard-and-fair failures, trials): a failure is a COMPLETE trial (some fair frame) whose mean confidence over
    its fair frames is below `hard_below`; every trial that ran counts in the denominator."""
    ran = [t for t in trials if t.state in ("COMPLETE", "PRUNED", "FAIL")]
    hard = [t for t in ran if t.state == "COMPLETE" and 1.0 - t.difficulty < hard_below]
    return len(hard), len(ran)


def images(datasets: list[Path]) -> list[Path]:
    return sorted(p for d in datasets for p in (d / "images").iterdir() if p.suffix == ".png")


def draw_frames(pool: list[Path], n: int, seed: int) -> list[Path]:
    """n frames drawn at random (seeded) from the pool; ValueError when it holds fewer."""
    if n > len(pool):
        raise ValueError(f"the random pool holds {len(pool)} frames, fewer than the {n} of the hard arm: "
                         "raise random_trials")
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


def assert_equal_budget(h: dict, r: dict) -> None:
    """The arms' trainings (their result.json) read as many frames, for as many epochs, at one image size."""
    unequal = {k: (h.get(k), r.get(k)) for k in BUDGET_KEYS if h.get(k) != r.get(k)}
    if unequal:
        raise AssertionError(f"unequal budgets between the arms (H, R): {unequal}")
