"""The archive's cells on the held-out sample, before and after training (issue 39 item 8).

Each held-out scenario falls in one cell of the archive of failure kinds: the search's descriptors (the same
`search.descriptors` every generator's search used) measured from the scenario's own frame table at its first
fairly visible frame, as the archive measures a trial. Every detector scored the same scenarios, so per cell and
detector group (D0; each arm's detectors of a round, its training seeds pooled) the share of the cell's scenarios
it failed says which kinds of failure training removed and which resisted: `cells.csv` and one heatmap per group
(`cells_<group>.png`). A scenario without a fair frame has no cell (it cannot fail).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from garage_exp.loop.stats import wilson
from garage_exp.loop.steps import Trial
from garage_exp.search import archive


def cells_of(held: list[Trial], search) -> dict[int, tuple[int, ...]]:
    """Each complete held-out scenario's cell (by trial number); those without a fair frame or a value a category
    does not list have none."""
    grid = archive.Grid(search.descriptors)
    out = {}
    for t in held:
        if t.state != "COMPLETE" or t.output_dir is None:
            continue
        measured = archive.measure_trial(t.output_dir, None, search)  # no picture: luminance, if asked, is NaN
        cell = grid.index(measured) if measured else None
        if cell is not None:
            out[t.number] = cell
    return out


def cell_table(scores: pd.DataFrame, cells: dict[int, tuple[int, ...]], grid: archive.Grid) -> pd.DataFrame:
    """One row per cell holding held-out scenarios and detector group (arm and round; D0 is round 0): the cell's
    scenarios, the group's detectors, their failures there (seeds pooled) and the share failed."""
    held = scores[scores.suite == "heldout"]
    by_cell: dict[tuple[int, ...], list[int]] = {}
    for number, cell in cells.items():
        by_cell.setdefault(cell, []).append(number)
    rows = []
    for (k, arm), group in held.groupby(["round", "arm"], sort=True):
        failed = [set(f) for f in group.failed]
        for cell, numbers in sorted(by_cell.items()):
            hits = sum(len(f & set(numbers)) for f in failed)
            low, high = wilson(hits, len(numbers) * len(failed))  # seeds pooled, as the round table's pooled rate
            rows.append({"cell": grid.name(cell), "index": list(cell), "arm": arm, "round": int(k),
                         "scenarios": len(numbers), "detectors": len(failed), "failures": hits,
                         "failed_share": hits / (len(numbers) * len(failed)), "low": low, "high": high})
    return pd.DataFrame(rows)


def reach(cells: dict[int, tuple[int, ...]], grid: archive.Grid) -> dict:
    """How many of the grid's cells the held-out sample reaches (holds a scenario of), of how many."""
    import math

    return {"reached": len(set(cells.values())), "cells": math.prod(grid.dims)}


def resisted(table: pd.DataFrame, arm: str, k: int, share: float = 0.5) -> list[str]:
    """The cells an arm's round-k detectors still fail in at least `share` of their scenarios (seeds pooled)."""
    part = table[(table.arm == arm) & (table["round"] == k) & (table.failed_share >= share)]
    return part.cell.tolist()


def draw(table: pd.DataFrame, grid: archive.Grid, out: Path, k: int) -> list[Path]:
    """cells_D0.png and cells_<arm>.png (round k): each cell's share of held-out scenarios failed, with how many
    scenarios it holds."""
    paths = []
    for (rnd, arm), part in table.groupby(["round", "arm"], sort=True):
        if int(rnd) not in (0, k):
            continue
        values = {tuple(r["index"]): r["failed_share"] for _, r in part.iterrows()}
        notes = {tuple(r["index"]): f"n={r['scenarios']}" for _, r in part.iterrows()}
        who = "D0" if arm == "D0" else f"arm {arm} after round {k} ({part.detectors.iloc[0]} seeds pooled)"
        failures, tests = int(part.failures.sum()), int((part.scenarios * part.detectors).sum())
        title = (f"{who}: share of each cell's held-out scenarios failed ({failures} of {tests} scenario tests; "
                 "grey: no held-out scenario there)")
        paths.append(archive.draw_cells(grid, values, out / f"cells_{arm}.png", title, "share failed",
                                        bold_at=0.5, notes=notes))
    return paths


def marginal_table(table: pd.DataFrame, grid: archive.Grid, k: int) -> pd.DataFrame:
    """Per descriptor and bin, the share of held-out scenario tests failed by D0 and by each arm after round k
    (the cells of that bin pooled, seeds pooled) with a Wilson interval: on a grid of hundreds of cells (the wide
    space's 864) the sample fills few scenarios per cell, and a bin of one descriptor pools many."""
    rows = []
    part = table[(table["round"] == 0) | (table["round"] == k)]
    for axis, d in enumerate(grid.descriptors):
        labels = grid.labels(axis)
        for (rnd, arm), group in part.groupby(["round", "arm"], sort=True):
            for b, label in enumerate(labels):
                inside = group[[int(i[axis]) == b for i in group["index"]]]
                tests = int((inside.scenarios * inside.detectors).sum())
                failed = int(inside.failures.sum())
                low, high = wilson(failed, tests)
                rows.append({"descriptor": d.source, "bin": label, "arm": arm, "round": int(rnd), "tests": tests,
                             "failures": failed, "failed_share": failed / tests if tests else float("nan"),
                             "low": low, "high": high})
    return pd.DataFrame(rows)


def draw_marginals(marginals: pd.DataFrame, path: Path) -> Path:
    """cells_marginals.png: one panel per descriptor, its bins' failed share per group, Wilson intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from garage_exp.loop.figure import COLOURS

    names = list(dict.fromkeys(marginals.descriptor))
    cols = min(3, len(names))
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.4 * rows), squeeze=False)
    groups = list(dict.fromkeys(zip(marginals["round"], marginals.arm)))
    width = 0.8 / max(1, len(groups))
    for ax, name in zip(axes.flat, names):
        part = marginals[marginals.descriptor == name]
        bins = list(dict.fromkeys(part.bin))
        for j, (rnd, arm) in enumerate(groups):
            g = part[(part["round"] == rnd) & (part.arm == arm)].set_index("bin").reindex(bins)
            x = np.arange(len(bins)) + (j - (len(groups) - 1) / 2) * width
            share = g.failed_share.fillna(0).to_numpy()
            err = [(g.failed_share - g.low).fillna(0).clip(lower=0), (g.high - g.failed_share).fillna(0).clip(lower=0)]
            ax.bar(x, share, width, yerr=err, capsize=2, color=COLOURS.get(arm), label=arm if rnd == 0 else
                   f"{arm} (round {rnd})")
        ax.set_xticks(np.arange(len(bins)), [f"{b}\nn={int(part[part.bin == b].tests.max())}" for b in bins],
                      fontsize=7)
        ax.set_ylim(0, 1)
        ax.set_title(name, fontsize=9)
        ax.set_ylabel("share failed", fontsize=8)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("Held-out failures by descriptor (cells pooled, seeds pooled; 95 % Wilson; n: scenario tests)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
