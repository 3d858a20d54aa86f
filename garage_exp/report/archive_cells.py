"""The archive of failure kinds as a study leaves it (issue 39; in the report since issue 47, item 8): each complete
trial with descriptors in its cell, a cell's elite (its hardest trial), `archive.csv` (one row per filled cell, with
its rerun command), `archive.png` (the heatmap), the coverage and the QD score, and the report's section on them.

The study records its cells when the search writes them (`RECORDED`: its descriptors and failure level, plain
data), so that `python -m garage_exp.report.search_analysis` writes the same files for any study. The search
(garage_exp/search/archive.py) measures the descriptors and proposes trials; this module only reads the study.
"""

from __future__ import annotations

import math
import shlex
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import optuna
import pandas as pd
from optuna.trial import FrozenTrial, TrialState

RECORDED = "archive"  # the study's user attribute: {"descriptors": [...], "failure": 0.6}


@dataclass(frozen=True)
class Axis:
    """One descriptor as plain values (a config node's `values` would be its method)."""

    source: str
    values: tuple[str, ...]
    edges: tuple[float, ...]
    merge: tuple[tuple[str, str], ...] = ()  # a category's unlisted value -> the listed value whose cell it joins


class Grid:
    """The archive's cells: each descriptor's bins, and a trial's cell from its measured values."""

    def __init__(self, descriptors):
        self.descriptors = [Axis(str(d["source"]), tuple(str(v) for v in (d.get("values") or [])),
                                 tuple(float(e) for e in (d.get("edges") or [])),
                                 tuple((str(k), str(v)) for k, v in dict(d.get("merge") or {}).items()))
                            for d in descriptors]

    @property
    def dims(self) -> list[int]:
        return [len(d.values) if d.values else len(d.edges) - 1 for d in self.descriptors]

    def labels(self, k: int) -> list[str]:
        d = self.descriptors[k]
        if d.values:
            return [str(v) for v in d.values]
        return [f"{a:g}-{b:g}" for a, b in zip(d.edges, d.edges[1:])]

    def index(self, measured: dict) -> tuple[int, ...] | None:
        """Each descriptor's bin; None when a value is missing, NaN, or neither among a category's values nor
        merged into one of them."""
        cell = []
        for d in self.descriptors:
            value = measured.get(d.source)
            if d.values:
                value = dict(d.merge).get(str(value), str(value))
                if value not in d.values:
                    return None
                cell.append(d.values.index(value))
            else:
                if value is None or not math.isfinite(float(value)):
                    return None
                bins = len(d.edges) - 1
                cell.append(int(np.clip(np.searchsorted(np.asarray(d.edges, float), float(value), "right") - 1,
                                        0, bins - 1)))
        return tuple(cell)

    def name(self, cell: tuple[int, ...]) -> str:
        return " | ".join(self.labels(k)[i] for k, i in enumerate(cell))


def elite_trials(trials: list[FrozenTrial], grid: Grid) -> dict[tuple[int, ...], FrozenTrial]:
    """Each cell's elite among the complete trials with descriptors, in trial order: a trial replaces a cell's
    elite only when strictly harder (an equal one leaves the earlier)."""
    best: dict[tuple[int, ...], FrozenTrial] = {}
    for trial in sorted(trials, key=lambda t: t.number):
        if trial.state != TrialState.COMPLETE or not trial.values:
            continue
        cell = grid.index(trial.user_attrs.get("descriptors") or {})
        if cell is None:
            continue
        if cell not in best or trial.values[0] > best[cell].values[0]:
            best[cell] = trial
    return best


def summary(trials: list[FrozenTrial], cells: dict) -> dict:
    """The archive's numbers: cells in all, cells filled, cells holding a hard-and-fair failure (coverage: their
    share of all cells) and the QD score (the sum of the elites' difficulties, ribs' qd_score with offset 0)."""
    grid = Grid(cells["descriptors"])
    elites = elite_trials(trials, grid)
    failure = float(cells["failure"])
    n = int(np.prod(grid.dims))
    failures = sum(1 for t in elites.values() if t.values[0] >= failure)
    return {"archive_cells": n, "archive_filled": len(elites), "archive_failure_cells": failures,
            "archive_coverage": failures / n, "archive_qd_score": float(sum(t.values[0] for t in elites.values()))}


def rerun_command(trial: FrozenTrial) -> str:
    from garage_exp.report.trials import rerun_overrides

    return " ".join(["python -m garage_exp", *map(shlex.quote, rerun_overrides(trial))])


def archive_table(trials: list[FrozenTrial], cells: dict) -> pd.DataFrame:
    """archive.csv: one row per filled cell (its elite): the cell, each descriptor's measured value, the
    difficulty, whether it is a hard-and-fair failure, the trial, its parameters and the command that reruns it."""
    grid = Grid(cells["descriptors"])
    rows = []
    for cell, trial in sorted(elite_trials(trials, grid).items()):
        measured = trial.user_attrs["descriptors"]
        rows.append({"cell": grid.name(cell), **{d.source: measured[d.source] for d in grid.descriptors},
                     "difficulty": round(trial.values[0], 6),
                     "failure": trial.values[0] >= float(cells["failure"]), "trial": trial.number,
                     **{f"param.{k}": v for k, v in trial.params.items()}, "rerun": rerun_command(trial)})
    columns = ["cell", *[d.source for d in grid.descriptors], "difficulty", "failure", "trial"]
    return pd.DataFrame(rows, columns=None if rows else [*columns, "rerun"])


def heatmap(trials: list[FrozenTrial], cells: dict, path: Path) -> Path:
    """Difficulty per cell: each cell's elite's, a failure cell's value in bold (draw_cells)."""
    grid = Grid(cells["descriptors"])
    failure = float(cells["failure"])
    numbers = summary(trials, cells)
    values = {cell: trial.values[0] for cell, trial in elite_trials(trials, grid).items()}
    title = (f"difficulty of each cell's elite ({numbers['archive_filled']}/{numbers['archive_cells']} cells "
             f"filled, {numbers['archive_failure_cells']} hard-and-fair failures >= {failure:g}, bold; "
             f"QD score {numbers['archive_qd_score']:.2f})")
    return draw_cells(grid, values, path, title, "difficulty", bold_at=failure)


# More panels than this and only those holding a value are drawn, WRAP to a row.
MAX_PANELS, WRAP = 12, 6


def draw_cells(grid: Grid, values: dict, path: Path, title: str, label: str, bold_at: float = 1.0,
               notes: dict | None = None) -> Path:
    """A value in [0, 1] per cell: the first two descriptors as a panel's rows and columns, one panel per
    combination of the others' bins (the third's down, the rest across); a cell without a value grey, a value at
    least `bold_at` in bold, `notes` (cell -> text) under a cell's value (e.g. how many scenarios it holds)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dims = grid.dims + [1] * max(0, 2 - len(grid.dims))
    rest = [range(n) for n in dims[2:]]
    panels = [()] if not rest else [tuple(p) for p in np.ndindex(*[len(r) for r in rest])]
    rows = dims[2] if len(dims) > 2 else 1  # the third descriptor's bins down, the others' across
    cols = len(panels) // rows
    left_out = 0
    if len(panels) > MAX_PANELS:  # a wide space (6 descriptors: 54 panels) drew a strip too wide to read
        held = {(tuple(c) + (0,) * (len(dims) - len(c)))[2:] for c in values} or {panels[0]}
        left_out = len(panels) - len(held)
        panels = [p for p in panels if p in held]
        cols = min(len(panels), WRAP)
        rows = -(-len(panels) // cols)
        title += f" ({left_out} panels without a value left out)"
    fig, axes = plt.subplots(rows, cols, figsize=(1.5 + 0.75 * max(dims[1], 2) * cols,
                                                  1.0 + (0.45 * dims[0] + 1.1) * rows),
                             squeeze=False, layout="constrained")
    for ax in axes.flat[len(panels):]:
        ax.set_axis_off()
    cmap = plt.get_cmap("magma_r").copy()
    cmap.set_bad("0.85")
    image = None
    for ax, panel in zip(axes.flat, panels):
        shown = np.full(dims[:2], np.nan)
        texts = {}
        for cell, value in values.items():
            full = tuple(cell) + (0,) * (len(dims) - len(cell))
            if full[2:] == panel:
                shown[full[0], full[1]] = value
                texts[full[:2]] = (notes or {}).get(cell, "")
        image = ax.imshow(shown, cmap=cmap, vmin=0.0, vmax=1.0, aspect="auto")
        for (i, j), v in np.ndenumerate(shown):
            if not np.isnan(v):
                note = texts.get((i, j), "")
                ax.text(j, i, f"{v:.2f}" + (f"\n{note}" if note else ""), ha="center", va="center", fontsize=7,
                        color="white" if v > 0.55 else "black", fontweight="bold" if v >= bold_at else "normal")
        ax.set_yticks(range(dims[0]), grid.labels(0) if len(grid.dims) > 0 else [""], fontsize=7)
        ax.set_xticks(range(dims[1]), grid.labels(1) if len(grid.dims) > 1 else [""], fontsize=7)
        name = ", ".join(f"{grid.descriptors[k + 2].source} {grid.labels(k + 2)[i]}" for k, i in enumerate(panel))
        ax.set_title(textwrap.fill(name, max(24, int(0.75 * max(dims[1], 2) * 14))) or "all", fontsize=7)
        ax.set_ylabel(str(grid.descriptors[0].source), fontsize=7)
        ax.set_xlabel(str(grid.descriptors[1].source) if len(grid.dims) > 1 else "", fontsize=7)
    fig.suptitle(textwrap.fill(title, int(fig.get_figwidth() * 12)), fontsize=8)  # ~12 characters an inch
    fig.colorbar(image, ax=axes, shrink=0.6, label=label)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write(study: optuna.Study, cells: dict, out_dir: Path) -> tuple[list[Path], dict]:
    """archive.csv and archive.png into out_dir, and the archive's numbers; nothing when no complete trial has
    descriptors (another objective, a dry run)."""
    trials = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not any("descriptors" in t.user_attrs for t in trials):
        return [], {}
    out_dir.mkdir(parents=True, exist_ok=True)
    table = archive_table(trials, cells)
    table.to_csv(out_dir / "archive.csv", index=False)
    return [out_dir / "archive.csv", heatmap(trials, cells, out_dir / "archive.png")], summary(trials, cells)


def recorded(study: optuna.Study) -> dict | None:
    """The cells the study's search recorded ({"descriptors", "failure"}), or None (a study of another objective,
    or one made before studies recorded them)."""
    return study.user_attrs.get(RECORDED)


def section(study: optuna.Study, out_dir: Path) -> tuple[list[str], list[Path], dict]:
    """The report's section on the archive (its coverage, links to archive.csv and archive.png, the heatmap),
    the files written and the numbers; nothing for a study without recorded cells or descriptors."""
    cells = recorded(study)
    if not cells:
        return [], [], {}
    files, numbers = write(study, cells, out_dir)
    if not files:
        return [], [], {}
    lines = ["## The archive of failure kinds", "",
             f"{numbers['archive_failure_cells']} of {numbers['archive_cells']} cells hold a hard-and-fair failure "
             f"(difficulty >= {float(cells['failure']):g}; coverage {numbers['archive_coverage']:.3f}), "
             f"{numbers['archive_filled']} filled, QD score {numbers['archive_qd_score']:.2f} (the sum of the "
             "elites' difficulties). Cells by "
             + ", ".join(f"`{d['source']}`" for d in cells["descriptors"])
             + ", measured at each trial's first fair frame. Each filled cell's elite, with the command that reruns "
             "it: [archive.csv](archive.csv); the heatmap: [archive.png](archive.png).", "",
             "![the archive: difficulty of each cell's elite](archive.png)", ""]
    return lines, files, numbers
