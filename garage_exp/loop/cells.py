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
