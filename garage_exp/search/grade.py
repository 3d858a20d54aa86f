"""Graded levels, measured: does a suite's level say how often fresh scenarios fail?

`search.suite.levels=N` gives a suite N levels of equal width on the composite confidence over the fair frames
(level 1 the easiest, confidence >= 1 - 1/N; level N the hardest, under 1/N) in place of its bands. A level is a
claim about a region of the space, not only about the K scenarios the suite keeps from it: scenarios drawn anew
near them should fail about as often, and more often at a higher level.

`python -m garage_exp.search.grade --storage URL --study SUITE` measures that claim on a finished suite's study:
1. **Fresh draws.** For each level, `fresh` new scenarios: a trial of the level picked at random, each of its
   continuous searched values moved by a Gaussian of `sigma` of its range (on a log axis for a log range) and
   reflected off the range's ends, its choices and its searched seeds kept (`plan.seed`, `palette.seed`,
   `light.seed`: a seed names a garage, a set of parked cars, the failed lamps; 5 % of its range is another one,
   not a near one), and a new `seed` (the seeded variation a replicate draws: the target's model, offset and yaw,
   the materials' stains). Never one of the suite's own scenarios.
2. **Rendered as the suite was.** They are enqueued, each with its level, in a study of their own beside the suite's
   (`<suite>-grade-<seed>`), which the suite's own command runs (its space and fixed values, `seed` searched), with
   the random sampler filling nothing: the study holds exactly the fresh draws.
3. **Scored.** A fresh draw fails when its difficulty reaches `--failure` (the archive's failure level, 0.6: the
   detector's mean confidence over the fair frames at most 0.4); a draw with no fair frame (or rejected by the
   space's requirements) tests nothing and is counted apart. Each level's failure rate has a Wilson interval, and
   Spearman's rho between level and failure rate says whether the levels are graded.
It writes grade.csv (a row per level) and grade.png (the rates with their intervals) and prints the rates and rho.
"""

from __future__ import annotations

import math
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import optuna.distributions as od
import pandas as pd

from garage_exp.core.errors import GarageError
from garage_exp.search.suite import LEVEL, band_of, level_bands

# Keys a fresh draw's command sets itself (the rest of the suite's command is kept as it was).
OWN = ("search.trials=", "search.study=", "search.sampler=", "search.mode=", "search.suite.", "search.seed=",
       "search.startup=", "resume=", "seed=", "hydra.sweep.dir=")


def level_of(band: str) -> int:
    return int(band[len(LEVEL):])


def nudged(value, dist: od.BaseDistribution, sigma: float, rng: np.random.Generator):
    """`value` moved by a Gaussian of `sigma` of its range, reflected off the ends (a choice stays)."""
    if isinstance(dist, od.CategoricalDistribution):
        return value
    low, high = float(dist.low), float(dist.high)
    log = bool(getattr(dist, "log", False))
    if log:
        low, high, value = math.log(low), math.log(high), math.log(value)
    span = high - low
    moved = float(value) + rng.normal(0.0, sigma * span) if span > 0 else float(value)
    if span > 0:  # reflect into [low, high]: a triangle wave of period 2 span
        t = (moved - low) % (2 * span)
        moved = low + (t if t <= span else 2 * span - t)
    if log:
        moved = math.exp(moved)
    if isinstance(dist, od.IntDistribution):
        step = dist.step or 1
        return int(min(max(dist.low + round((moved - dist.low) / step) * step, dist.low), dist.high))
    return float(min(max(moved, float(dist.low)), float(dist.high)))


def is_seed(key: str) -> bool:
    """A searched seed (`plan.seed`, `light.seed` ...): a name for one generated thing, with no near values."""
    return key == "seed" or key.endswith(".seed")


def level_members(study, levels: int) -> dict[int, list]:
    """Each level's complete trials (every one, not only those the suite kept: the level is their region)."""
    from optuna.trial import TrialState

    bands = level_bands(levels)
    out: dict[int, list] = {k: [] for k in range(1, levels + 1)}
    for trial in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        band = band_of(1.0 - trial.values[0], bands)
        if band is not None:
            out[level_of(band)].append(trial)
    return out


def fresh_draws(study, levels: int, per_level: int, sigma: float, seed: int) -> list[tuple[int, dict]]:
    """(level, params) for `per_level` fresh draws of each level that has trials, deterministic for the seed; each
    params holds the suite's searched keys, nudged (its seeds kept), and a new `seed`."""
    rng = np.random.default_rng(seed)
    out = []
    for level, trials in level_members(study, levels).items():
        trials = sorted(trials, key=lambda t: t.number)
        for _ in range(per_level if trials else 0):
            member = trials[int(rng.integers(len(trials)))]
            params = {k: v if is_seed(k) else nudged(v, member.distributions[k], sigma, rng)
                      for k, v in member.params.items()}
            params["seed"] = int(rng.integers(1_000_000))
            out.append((level, params))
    return out


def command_of(study) -> list[str]:
    """The suite's command line (its overrides, as its sweeper recorded them)."""
    argv = study.user_attrs.get("argv")
    if argv:
        return list(argv)
    command = study.user_attrs.get("command")
    if not command:
        raise GarageError(f"study {study.study_name!r} records no command (not a search's study?)", "--study")
    return shlex.split(command)


def grade_command(suite_argv: list[str], storage: str, name: str, trials: int, sweep_dir: Path) -> list[str]:
    """The suite's own command, run over the enqueued fresh draws: its space and fixed values, `seed` searched."""
    kept = [a for a in suite_argv if not a.startswith(OWN) and not a.startswith("search.storage=")]
    return [sys.executable, "-m", "garage_exp", "-m", "hydra/sweeper=search", *kept, "seed=int(interval(0,999999))",
            "search.mode=search",
            "search.sampler=random", f"search.trials={trials}", f"search.study={name}", f"search.storage={storage}",
            f"hydra.sweep.dir={sweep_dir}"]


def enqueue(study, draws: list[tuple[int, dict]]) -> None:
    """The fresh draws, each with its level, into the grade study (a resumed one already holds them)."""
    if study.get_trials(deepcopy=False):
        return
    for k, (level, params) in enumerate(draws):
        study.enqueue_trial(params, user_attrs={"grade_level": level, "grade_draw": k})


def measure(study, failure: float) -> tuple[pd.DataFrame, float]:
    """Each level's fresh draws: drawn, scored (a fair frame), failed (difficulty >= `failure`), the failure rate
    among the scored with its Wilson interval; and Spearman's rho between level and rate (NaN with fewer than
    three scored levels)."""
    from optuna.trial import TrialState
    from scipy.stats import spearmanr

    from garage_exp.results.stats import wilson

    rows: dict[int, dict] = {}
    for t in study.get_trials(deepcopy=False):
        level = t.user_attrs.get("grade_level")
        if level is None or t.state in (TrialState.WAITING, TrialState.RUNNING):
            continue
        row = rows.setdefault(int(level), {"level": int(level), "drawn": 0, "scored": 0, "failed": 0, "sum": 0.0})
        row["drawn"] += 1
        if t.state == TrialState.COMPLETE:
            row["scored"] += 1
            row["failed"] += int(t.values[0] >= failure)
            row["sum"] += float(t.values[0])
    table = pd.DataFrame(sorted(rows.values(), key=lambda r: r["level"]),
                         columns=["level", "drawn", "scored", "failed", "sum"])
    # the mean difficulty too: it shows the grading where few draws reach the failure level
    table["difficulty"] = [s / n if n else math.nan for s, n in zip(table.pop("sum"), table.scored)]
    bounds = [wilson(int(f), int(n)) for f, n in zip(table.failed, table.scored)]
    table["failure_rate"] = [f / n if n else math.nan for f, n in zip(table.failed, table.scored)]
    table["low"] = [b[0] for b in bounds]
    table["high"] = [b[1] for b in bounds]
    scored = table[table.scored > 0]
    rho = float(spearmanr(scored.level, scored.failure_rate).statistic) if len(scored) >= 3 else math.nan
    return table, rho


def figure(table: pd.DataFrame, rho: float, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.0, 3.4))
    rate = table.failure_rate.to_numpy(float)
    err = np.vstack([rate - table.low.to_numpy(float), table.high.to_numpy(float) - rate])
    ax.errorbar(table.level, rate, yerr=err, fmt="o-", capsize=4)
    ax.set_xlabel("suite level (1 easiest)")
    ax.set_ylabel("failure rate of fresh draws")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xticks(list(table.level))
    ax.set_title(f"{title}\nSpearman rho {rho:.2f}", fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def grade(storage: str, suite: str, out: Path, levels: int = 5, fresh: int = 20, sigma: float = 0.05, seed: int = 0,
          failure: float = 0.6, run=None) -> tuple[pd.DataFrame, float]:
    """Draw, render and score the suite's fresh draws (module doc); `run(cmd)` runs the grade command and returns
    its exit code (default: a child process, stopped with this one)."""
    import optuna
    from omegaconf import OmegaConf

    from garage_exp.core.exits import wait_child
    from garage_exp.search.schema import SearchConf
    from garage_exp.search.storage import open_storage
    from garage_exp.search.study import open_study

    store = open_storage(storage)
    try:
        suite_study = optuna.load_study(study_name=suite, storage=store)
    except KeyError:
        raise GarageError(f"no study {suite!r} in {storage}", "--study") from None
    argv = command_of(suite_study)
    draws = fresh_draws(suite_study, levels, fresh, sigma, seed)
    if not draws:
        raise GarageError(f"study {suite!r} has no complete trial in any of its {levels} levels", "--study")
    name = f"{suite}-grade-{seed}"
    goal = next((a.split("=", 1)[1] for a in argv if a.startswith("search.objective=")), "difficulty")
    # made as the search makes its studies (its objective's directions and names), so that the search takes it
    search = OmegaConf.structured(SearchConf(storage=storage, study=name, sampler="random", objective=goal))
    enqueue(open_study(search, name, seed), draws)
    out.mkdir(parents=True, exist_ok=True)
    cmd = grade_command(argv, storage, name, len(draws), out / "sweep")
    print(f"garage_exp: {len(draws)} fresh draws of study {suite!r}: their search's output in {out / 'search.log'}")
    with open(out / "search.log", "w") as log:  # the child's own lines, apart from this command's
        code = (run or (lambda c: wait_child(c, stdout=log, stderr=subprocess.STDOUT)))(cmd)
    if code not in (0, 1):  # 1: some fresh draws failed to run (their trials say why); the others count
        raise RuntimeError(f"the fresh draws' search failed (exit {code}; {out / 'search.log'}): {shlex.join(cmd)}")
    grade_study = optuna.load_study(study_name=name, storage=store)
    table, rho = measure(grade_study, failure)
    table.to_csv(out / "grade.csv", index=False)
    figure(table, rho, out / "grade.png", f"study {suite}: {fresh} fresh draws a level, sigma {sigma}")
    return table, rho


def main(argv: list[str] | None = None) -> int:
    import argparse

    from garage_exp.core import shell

    parser = argparse.ArgumentParser(prog="python -m garage_exp.search.grade",
                                     description="Measure a graded suite on fresh draws of each level.")
    parser.add_argument("--storage", required=True, help="the suite study's Optuna storage URL")
    parser.add_argument("--study", required=True, help="the suite's study name")
    parser.add_argument("--levels", type=int, default=5, help="the suite's levels (search.suite.levels)")
    parser.add_argument("--fresh", type=int, default=20, help="fresh draws per level")
    parser.add_argument("--sigma", type=float, default=0.05, help="each value's nudge, as a share of its range")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--failure", type=float, default=0.6, help="a draw fails at this difficulty or more")
    parser.add_argument("-o", "--out", default="outputs/grade", help="where grade.csv and grade.png go")

    def body(args) -> None:
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        if args.storage.startswith("sqlite:///") and not Path(args.storage.removeprefix("sqlite:///")).is_file():
            raise GarageError("no such file", args.storage)  # sqlite would create an empty store
        if args.fresh < 1:
            raise GarageError(f"{args.fresh} fresh draws: at least 1", "--fresh")
        if not 0.0 < args.sigma <= 1.0:
            raise GarageError(f"{args.sigma}: a share of a range in (0, 1]", "--sigma")
        if not 0.0 < args.failure <= 1.0:
            raise GarageError(f"{args.failure}: a difficulty in (0, 1]", "--failure")
        level_bands(args.levels)
        table, rho = grade(args.storage, args.study, Path(args.out), args.levels, args.fresh, args.sigma,
                           args.seed, args.failure)
        for row in table.itertuples():
            print(f"garage_exp: level {row.level}: {row.failed} of {row.scored} fresh draws failed "
                  f"({row.failure_rate:.2f}, 95 % CI {row.low:.2f}-{row.high:.2f}; mean difficulty "
                  f"{row.difficulty:.2f}; {row.drawn - row.scored} not fair)")
        print(f"garage_exp: Spearman rho between level and failure rate: {rho:.2f}; {Path(args.out) / 'grade.csv'}")

    return shell.Command("garage_exp.search.grade").run_args(parser, body, argv)


if __name__ == "__main__":
    sys.exit(main())
