"""The loop's figure: failures per 100 held-out scenarios by round and arm (the seeds' mean, 95 % t interval; D0 at
round 0), and after the last round each arm's recall on the easy suite, the protocol suite and the real photos
against D0's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

COLOURS = {"D0": "#7f7f7f", "R": "#1f77b4", "T": "#d62728", "Q": "#2ca02c"}


def draw(rounds: pd.DataFrame, scores: pd.DataFrame, photos: pd.DataFrame, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.2))
    d0 = rounds[rounds.arm == "D0"]
    arms = [a for a in dict.fromkeys(rounds.arm) if a != "D0"]
    for j, arm in enumerate(arms):
        part = pd.concat([d0, rounds[rounds.arm == arm]]).sort_values("round")
        x = part["round"].to_numpy() + (j - (len(arms) - 1) / 2) * 0.04
        low = (part.per_100 - part.low).fillna(0).clip(lower=0)
        high = (part.high - part.per_100).fillna(0).clip(lower=0)
        ax.errorbar(x, part.per_100, yerr=[low, high], fmt="o-", capsize=3, color=COLOURS.get(arm, None),
                    label=f"{arm}")
    ax.set_xticks(sorted(rounds["round"].unique()))
    ax.set_ylim(0, 100)
    ax.set_xlabel("round (0: D0)")
    ax.set_ylabel("hard-and-fair failures per 100 held-out scenarios")
    one_seed = bool(len(rounds)) and int(rounds.seeds.max()) == 1  # report.round_table: one seed's own Wilson
    ax.set_title("Failure rate on the held-out sample (95 % " + ("Wilson, one seed)" if one_seed else "CI over seeds)"))
    ax.legend(fontsize=8)

    last = scores["round"].max()
    suites = [s for s in ("easy", "protocol") if s in set(scores.suite)]
    table = {s: scores[(scores.suite == s) & scores["round"].isin([0, last])].groupby("arm").fair_recall.mean()
             for s in suites}
    if len(photos):
        table["real photos"] = photos[photos["round"].isin([0, last])].groupby("arm").recall.mean()
    names = list(table)
    order = ["D0", *arms]
    width = 0.8 / max(1, len(order))
    for j, arm in enumerate(order):
        values = [float(table[n].get(arm, np.nan)) for n in names]
        x = np.arange(len(names)) + (j - (len(order) - 1) / 2) * width
        bars = bx.bar(x, values, width, color=COLOURS.get(arm, None), label=arm)
        bx.bar_label(bars, fmt="%.2f", fontsize=7, padding=2)
    bx.set_xticks(range(len(names)), names)
    bx.set_ylim(0, 1.08)
    bx.set_ylabel("recall (mean over seeds)")
    bx.set_title(f"After round {last}: what must not be forgotten")
    bx.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
