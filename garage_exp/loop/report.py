"""The loop's results: every detector scored on the held-out suites, summarised per arm with intervals over the
training seeds, failures per 100 trials before and after, a figure and a page (results/loop.md).

Intervals: for an arm, the mean over its seeds +- Student's t (n - 1 degrees of freedom) x the standard error;
H - R is paired by seed (the same seed draws the same replay); failures per 100 trials are Wilson intervals.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from garage_exp.loop import budget
from garage_exp.loop.evaluate import evaluate
from garage_exp.results.stats import wilson

METRICS = ("fair_recall", "fair_difficulty", "map50")


def weights_of(result: dict) -> Path:
    return Path(result["weights"])


class Suites(dict):
    """The held-out suites by name (a dict, as the evaluation reads them) and `note`: why the split into hard and
    easy means little or nothing ("" when the hard suite's trials are all harder than the easy suite's)."""

    note: str = ""


def heldout_suites(cfg, held: list, d0: dict) -> Suites:
    """The held-out hard and easy suites: the hardest and the easiest third of the held-out study's fairly visible
    trials, by D0's fair difficulty (scored here on the trials' frames) or by the shipped detectors' (the study's)."""
    from garage_exp.loop.evaluate import score_frames

    done = [t for t in held if t.state == "COMPLETE" and t.dataset is not None]
    if cfg.heldout_graded_by == "d0":
        frames = score_frames(weights_of(d0), int(cfg.imgsz), done, float(cfg.threshold))
        fair = frames[frames.fair].groupby("trial").confidence.mean()
        done = [t for t in done if t.number in fair.index]
        key = {t.number: 1.0 - float(fair[t.number]) for t in done}
    else:
        key = {t.number: t.difficulty for t in done}
    done.sort(key=lambda t: (-key[t.number], t.number))
    third = max(1, len(done) // 3)
    suites = Suites(hard=done[:third], easy=done[-third:])
    suites.note = split_note([key[t.number] for t in done], third,
                             "D0's" if cfg.heldout_graded_by == "d0" else "the shipped detectors'")
    if suites.note:
        print(f"garage_exp.loop: {suites.note}")
    return suites


def split_note(keys: list[float], third: int, whose: str) -> str:
    """Why a split of `keys` (hardest first) into its first and last `third` cannot mean much: too few trials,
    or ties across it (D0 finding nothing in any trial puts every one at difficulty 1). "" when it can."""
    if len(keys) < 2:
        return (f"{len(keys)} fairly visible held-out trial(s): the hard and the easy suite are the same "
                "scenarios, not a split")
    hard, easy = keys[:third], keys[-third:]
    if min(hard) > max(easy):
        return ""
    tied = sum(1 for k in keys if k == min(hard))
    if max(keys) == min(keys):
        return (f"{whose} fair difficulty is {keys[0]:.2f} for all {len(keys)} held-out trials: the hard and the "
                "easy suite are an arbitrary split (by trial number), not a graded one; their results do not compare "
                "hard with easy")
    return (f"{tied} held-out trials tie at {whose} fair difficulty {min(hard):.2f} across the split: the hard "
            "and the easy suite are partly an arbitrary split (by trial number)")


def evaluate_all(cfg, models: dict[str, dict[int, dict]], suites: dict) -> dict:
    """{"scores": one row per (model, seed, suite), "frames": every scored frame}."""
    rows, frames = [], []
    for arm, by_seed in models.items():
        for seed, result in by_seed.items():
            for suite, trials in suites.items():
                summary, table = evaluate(weights_of(result), int(cfg.imgsz), trials, float(cfg.threshold))
                rows.append({"arm": arm, "seed": seed, "suite": suite, **summary})
                frames.append(table.assign(arm=arm, seed=seed, suite=suite))
    return {"scores": pd.DataFrame(rows), "frames": pd.concat(frames, ignore_index=True)}


def t_interval(values) -> tuple[float, float, float]:
    """(mean, low, high) of a 95 % Student's t interval; a single value has no interval (NaN ends)."""
    from scipy import stats

    v = np.asarray([x for x in values if not (isinstance(x, float) and math.isnan(x))], dtype=float)
    if len(v) == 0:
        return math.nan, math.nan, math.nan
    mean = float(v.mean())
    if len(v) < 2:
        return mean, math.nan, math.nan
    half = float(stats.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))
    return mean, mean - half, mean + half


def arm_table(scores: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (suite, arm), g in scores.groupby(["suite", "arm"], sort=False):
        row = {"suite": suite, "arm": arm, "seeds": len(g)}
        for m in METRICS:
            row[m], row[f"{m}_low"], row[f"{m}_high"] = t_interval(g[m])
        rows.append(row)
    return pd.DataFrame(rows)


def paired(scores: pd.DataFrame) -> pd.DataFrame:
    """H - R per seed, by suite and metric, with its t interval."""
    rows = []
    for suite, g in scores.groupby("suite", sort=False):
        h = g[g.arm == "H"].set_index("seed")
        r = g[g.arm == "R"].set_index("seed")
        seeds = sorted(set(h.index) & set(r.index))
        for m in METRICS:
            mean, low, high = t_interval([h.loc[s, m] - r.loc[s, m] for s in seeds])
            rows.append({"suite": suite, "metric": m, "H_minus_R": mean, "low": low, "high": high, "seeds": len(seeds)})
    return pd.DataFrame(rows)


def failure_table(rounds: dict, hard_below: float) -> pd.DataFrame:
    rows = []
    for name, trials in rounds.items():
        k, n = budget.failures(trials, hard_below)
        low, high = wilson(k, n)
        rows.append({"detector": name, "failures": k, "trials": n, "per_100": 100.0 * k / n if n else math.nan,
                     "low": 100.0 * low, "high": 100.0 * high})
    return pd.DataFrame(rows)


def missed_then_found(frames: pd.DataFrame, threshold: float, n: int = 3) -> pd.DataFrame:
    """Fair frames of the held-out hard suite that D0 missed and H (its first seed) found."""
    hard = frames[(frames.suite == "hard") & frames.fair]
    d0 = hard[hard.arm == "D0"].set_index("image").confidence
    h = hard[hard.arm == "H"]
    h = h[h.seed == h.seed.min()].set_index("image").confidence
    both = pd.DataFrame({"d0": d0, "h": h}).dropna()
    pick = both[(both.d0 < threshold) & (both.h >= threshold)].sort_values("h", ascending=False)
    return pick.head(n).reset_index()


def write(cfg, out: Path, result: dict, rounds: dict, suites: dict, hard: list, times: dict) -> dict:
    from garage_exp.loop.figure import draw

    out.mkdir(parents=True, exist_ok=True)
    scores, frames = result["scores"], result["frames"]
    scores.to_csv(out / "scores.csv", index=False)
    frames.to_csv(out / "frames.csv", index=False)
    arms = arm_table(scores)
    arms.to_csv(out / "arms.csv", index=False)
    diff = paired(scores)
    diff.to_csv(out / "h_minus_r.csv", index=False)
    fails = failure_table(rounds, float(cfg.hard_below))
    fails.to_csv(out / "failures.csv", index=False)
    found = missed_then_found(frames, float(cfg.threshold))
    found.to_csv(out / "missed_then_found.csv", index=False)
    draw(arms, fails, scores, found, out / "loop.png")
    note = getattr(suites, "note", "")
    summary = {"suites": {k: [f"{t.study}#{t.number}" for t in v] for k, v in suites.items()},
               "suite_split": note or "graded: every hard-suite trial harder than every easy-suite one",
               "hard_training_scenarios": [t.number for t in hard], "times_s": times}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(f"garage_exp.loop: results in {out} (scores.csv, arms.csv, h_minus_r.csv, failures.csv, loop.png)")
    if note:
        print(f"garage_exp.loop: held-out suites: {note}")
    print(arms.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    print(diff.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    print(fails.to_string(index=False, float_format=lambda v: f"{v:.1f}"))
    return summary
