"""The loop's figure: fair recall by arm on the held-out hard and easy suites (95 % intervals over the seeds),
failures per 100 trials before and after fine-tuning (Wilson intervals), recall by visible fraction on the hard
suite, and a few held-out frames D0 missed and the hard arm found."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

COLOURS = {"D0": "#7f7f7f", "H": "#d62728", "R": "#1f77b4"}


def _errors(df: pd.DataFrame, m: str) -> np.ndarray:
    low = (df[m] - df[f"{m}_low"]).fillna(0).clip(lower=0)
    high = (df[f"{m}_high"] - df[m]).fillna(0).clip(lower=0)
    return np.vstack([low.to_numpy(), high.to_numpy()])


def draw(arms: pd.DataFrame, fails: pd.DataFrame, scores: pd.DataFrame, found: pd.DataFrame, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    n_frames = len(found)
    fig = plt.figure(figsize=(13, 7.5 if n_frames else 4.2))
    grid = fig.add_gridspec(2 if n_frames else 1, 3, height_ratios=[1, 0.9] if n_frames else [1])
    ax = fig.add_subplot(grid[0, 0])
    order = [a for a in ("D0", "R", "H") if a in set(arms.arm)]
    width = 0.8 / len(order)
    for k, arm in enumerate(order):
        part = arms[arms.arm == arm].set_index("suite").reindex(["hard", "easy"]).reset_index()
        x = np.arange(2) + (k - (len(order) - 1) / 2) * width
        bars = ax.bar(x, part.fair_recall, width, yerr=_errors(part, "fair_recall"), capsize=3,
                      color=COLOURS[arm], label=arm)
        ax.bar_label(bars, fmt="%.2f", fontsize=7, padding=2)
    ax.set_xticks(range(2), ["held-out hard", "held-out easy"])
    ax.set_ylabel("recall on fair frames")
    ax.set_ylim(0, 1.05)
    ax.set_title("Recall by arm (95 % CI over seeds)")
    ax.legend(fontsize=8)

    ax = fig.add_subplot(grid[0, 1])
    x = np.arange(len(fails))
    err = np.vstack([(fails.per_100 - fails.low).clip(lower=0), (fails.high - fails.per_100).clip(lower=0)])
    bars = ax.bar(x, fails.per_100, 0.6, yerr=err, capsize=4,
                  color=[COLOURS.get(d, "#999") for d in fails.detector])
    ax.bar_label(bars, fmt="%.0f", fontsize=8, padding=2)
    ax.set_xticks(x, [f"{d}\n{f}/{n}" for d, f, n in zip(fails.detector, fails.failures, fails.trials)])
    ax.set_ylabel("hard-and-fair failures per 100 trials")
    ax.set_title("A search against each detector (Wilson 95 %)")

    ax = fig.add_subplot(grid[0, 2])
    bins = [c for c in scores.columns if c.startswith("recall_vis_")]
    hard = scores[scores.suite == "hard"]
    for arm in order:
        means = hard[hard.arm == arm][bins].mean()
        ax.plot(range(len(bins)), means.to_numpy(), "o-", color=COLOURS[arm], label=arm)
    ax.set_xticks(range(len(bins)), [b.removeprefix("recall_vis_") for b in bins], fontsize=8)
    ax.set_xlabel("target's visible fraction")
    ax.set_ylabel("recall (mean over seeds)")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("Held-out hard suite by visibility")
    ax.legend(fontsize=8)

    for k, row in enumerate(found.itertuples()):
        ax = fig.add_subplot(grid[1, k])
        ax.imshow(Image.open(row.image))
        ax.set_title(f"D0 {row.d0:.2f} -> H {row.h:.2f}", fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
