"""The archive of failure kinds (issue 39, item 1): quality-diversity search with pyribs over the declared space.

Each complete trial of a difficulty search is placed in a cell of a grid (ribs' GridArchive) by DESCRIPTORS
measured from its own outputs (`search.descriptors`, each a `source` registered in search/descriptors.py, binned by
`values` or `edges`): its frame table at the first fairly visible frame (who the target is, what hides it, how
far, how much of it is hidden, how lit it is, which camera at what height) and its picture (how dark). A category's value that is not among its `values` joins the
cell `merge` names for it (occluder: structure -> pillar, person -> vehicle); one neither listed nor merged
leaves the trial without a cell (it stays out of the archive, as a trial without a fair frame does). A cell keeps its hardest trial, the elite; a later trial replaces it only when
harder. A cell whose elite's difficulty is at least `search.archive.failure` holds a hard-and-fair failure.

`search.sampler=archive` proposes trials with ribs' MAP-Elites emitters (GaussianEmitter, or IsoLineEmitter),
asked over the space normalised to [0, 1] per parameter and mapped back to its values (a choice by binning).
Its emitters keep no state but the archive, so the sampler (an Optuna sampler: Optuna stays the study's store
and bookkeeping) rebuilds the archive from the study's complete trials at each ask and seeds the emitter with
the trial's number: a resumed study, a batch (`search.batch`, each trial another seed), a pre-screened trial and
several workers on one storage all see the same archive the storage holds. (CMA-ME's emitters keep a covariance
between asks that a resume would lose; MAP-Elites' does not.) The first `search.startup` trials are uniform.
"""

from __future__ import annotations

import logging
import math
import shlex
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import optuna
import optuna.distributions as od
import pandas as pd
from optuna.trial import FrozenTrial, TrialState

from garage_exp.core.errors import GarageError
from garage_exp.search.descriptors import CATEGORY, DESCRIPTORS, descriptor

log = logging.getLogger("garage_exp")
X_ATTR = "archive:x"  # the normalised point the archive sampler asked (system attr of the trial)
EMITTERS = ("gaussian", "iso_line")


# --- descriptors: measured from a trial's outputs (each registered in search/descriptors.py) --------------------

def check_descriptors(descriptors) -> None:
    """`search.descriptors`: a known source each, once, with `values` (a category, and a `merge` of other values
    into them) or increasing `edges` (a number); GarageError naming the entry."""
    seen = set()
    for k, d in enumerate(descriptors):
        where = f"search.descriptors[{k}]"
        source = str(d.get("source") or "")
        kind = descriptor(source, f"{where}.source").kind
        if source in seen:
            raise GarageError(f"the descriptor {source} is declared twice", f"{where}.source")
        seen.add(source)
        values, edges = list(d.get("values") or []), [float(e) for e in (d.get("edges") or [])]
        if kind == CATEGORY:
            if edges or len(values) < 1 or len(set(map(str, values))) != len(values):
                raise GarageError(f"{source} is a category: give its distinct values (values: [...]), no edges",
                                  where)
            for other, into in dict(d.get("merge") or {}).items():
                if str(other) in map(str, values) or str(into) not in map(str, values):
                    raise GarageError(f"merge {other} -> {into}: merge a value that is not listed into one that "
                                      f"is ({', '.join(map(str, values))})", f"{where}.merge")
        elif values or d.get("merge") or len(edges) < 2 or any(not a < b for a, b in zip(edges, edges[1:])):
            raise GarageError(f"{source} is a number: give at least two increasing edges (edges: [...]), not "
                              f"{edges or values}", where)


def measure(table: pd.DataFrame, out_dir: Path, frame, search) -> dict | None:
    """A trial's descriptors from its frame table (the first fairly visible frame of the primary camera: the
    table's first camera, as the search scores it) and its picture; None when no frame was fair."""
    from garage_exp.results.table import fair_mask

    if table.empty:
        return None
    primary = table[table.camera == table.camera.iloc[0]]
    fair = primary[fair_mask(primary, search)]
    if fair.empty:
        return None
    first = fair.iloc[0]
    return {str(d["source"]): DESCRIPTORS[str(d["source"])].measure(first, out_dir, frame) for d in search.descriptors}


def measure_trial(output_dir, frame, search) -> dict | None:
    """`measure` on a trial's job directory (its frames.csv); None when it left none (a job elsewhere)."""
    path = Path(str(output_dir)) / "frames.csv" if output_dir else None
    if path is None or not path.exists():
        return None
    return measure(pd.read_csv(path), path.parent, frame, search)


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


# --- the space normalised to [0, 1] per parameter --------------------------------------------------------------

def decode(x, params: dict[str, od.BaseDistribution]) -> dict:
    """A point of [0, 1]^d as the space's values: a choice by binning (n equal bins), an integer rounded to its
    step, a float linearly (a log one geometrically)."""
    out = {}
    for u, (name, dist) in zip(np.clip(np.asarray(x, float), 0.0, 1.0), params.items()):
        if isinstance(dist, od.CategoricalDistribution):
            out[name] = dist.choices[min(int(u * len(dist.choices)), len(dist.choices) - 1)]
        elif isinstance(dist, od.IntDistribution):
            step = dist.step or 1
            out[name] = int(dist.low + round(u * (dist.high - dist.low) / step) * step)
        elif dist.log:
            out[name] = float(math.exp(math.log(dist.low) + u * (math.log(dist.high) - math.log(dist.low))))
        else:
            out[name] = float(dist.low + u * (dist.high - dist.low))
    return out


def fold(x, params: dict[str, od.BaseDistribution]) -> np.ndarray:
    """A mutated point back into [0, 1]^d: a choice's coordinate wraps around (its choices have no order, so
    stepping past the last is as near the first as any other), a number's reflects at its ends. Clipping instead
    would pile every step past an end onto the end's value, and an elite there would keep its offspring at home."""
    out = []
    for u, dist in zip(np.asarray(x, float), params.values()):
        if isinstance(dist, od.CategoricalDistribution):
            out.append(u % 1.0)
        else:
            v = u % 2.0
            out.append(2.0 - v if v > 1.0 else v)
    return np.asarray(out, float)


def encode(values: dict, params: dict[str, od.BaseDistribution]) -> np.ndarray:
    """A trial's values as a point of [0, 1]^d (the middle of a choice's bin): for trials the archive sampler
    did not ask (another sampler's, an enqueued one)."""
    x = []
    for name, dist in params.items():
        v = values[name]
        if isinstance(dist, od.CategoricalDistribution):
            x.append((dist.choices.index(v) + 0.5) / len(dist.choices))
        elif getattr(dist, "log", False):
            x.append((math.log(v) - math.log(dist.low)) / (math.log(dist.high) - math.log(dist.low)))
        else:
            x.append((v - dist.low) / (dist.high - dist.low) if dist.high > dist.low else 0.5)
    return np.asarray(x, float)


# --- the archive ------------------------------------------------------------------------------------------------

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


def ribs_archive(trials: list[FrozenTrial], grid: Grid, params: dict, seed: int):
    """The trials as a ribs GridArchive over the normalised space: one axis per descriptor, the bin's index as
    its measure, the difficulty as the objective (ribs keeps the better one in a cell, as elite_trials does)."""
    from ribs.archives import GridArchive

    archive = GridArchive(solution_dim=len(params), dims=grid.dims, ranges=[(0, n) for n in grid.dims], seed=seed)
    for cell, trial in sorted(elite_trials(trials, grid).items(), key=lambda kv: kv[1].number):
        x = trial.system_attrs.get(X_ATTR)
        x = np.asarray(x, float) if x is not None else encode(trial.params, params)
        archive.add(x[None], np.array([trial.values[0]]), (np.asarray(cell, float) + 0.5)[None])
    return archive


class ArchiveSampler(optuna.samplers.BaseSampler):
    """Optuna's sampler interface around ribs' MAP-Elites emitters (see the module's doc)."""

    def __init__(self, params: dict, descriptors, seed: int, startup: int, emitter: str = "gaussian",
                 sigma: float = 0.15):
        self.params, self.grid, self.seed = dict(params), Grid(descriptors), int(seed)
        self.startup, self.emitter, self.sigma = int(startup), emitter, float(sigma)
        self._random = optuna.samplers.RandomSampler(seed=seed)

    def infer_relative_search_space(self, study, trial) -> dict:
        return dict(self.params)

    def ask_point(self, trials: list[FrozenTrial], number: int) -> np.ndarray:
        """The normalised point of trial `number`, from the archive of `trials`: uniform for the first
        `startup` trials and while the archive is empty, else the emitter's (seeded by the trial's number)."""
        from ribs.emitters import GaussianEmitter, IsoLineEmitter

        seeds = np.random.SeedSequence([self.seed, number]).generate_state(3)
        d = len(self.params)
        archive = ribs_archive(trials, self.grid, self.params, int(seeds[0]))
        if number < self.startup or archive.empty:
            return np.random.default_rng(int(seeds[1])).uniform(size=d)
        # Unbounded, then folded into the cube (fold): ribs' bounds clip, which piles every step past an end onto
        # the end, so an elite at an end of the space (the last case, the first light) kept most of its offspring
        # in its own cell (the first loop run's Q arm: 6 trials of one cell).
        if self.emitter == "iso_line":
            emitter = IsoLineEmitter(archive, iso_sigma=self.sigma, line_sigma=0.2, x0=np.full(d, 0.5),
                                     bounds=None, batch_size=1, seed=int(seeds[2]))
        else:
            emitter = GaussianEmitter(archive, sigma=self.sigma, x0=np.full(d, 0.5), bounds=None, batch_size=1,
                                      seed=int(seeds[2]))
        return fold(emitter.ask()[0], self.params)

    def sample_relative(self, study, trial, search_space) -> dict:
        if not search_space:
            return {}
        trials = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        x = self.ask_point(trials, trial.number)
        study._storage.set_trial_system_attr(trial._trial_id, X_ATTR, [float(v) for v in x])
        return decode(x, self.params)

    def sample_independent(self, study, trial, param_name, param_distribution):
        return self._random.sample_independent(study, trial, param_name, param_distribution)


# --- what a study leaves: archive.csv, the heatmap, coverage and QD score --------------------------------------

def summary(trials: list[FrozenTrial], search) -> dict:
    """The archive's numbers: cells in all, cells filled, cells holding a hard-and-fair failure (coverage: their
    share of all cells) and the QD score (the sum of the elites' difficulties, ribs' qd_score with offset 0)."""
    grid = Grid(search.descriptors)
    elites = elite_trials(trials, grid)
    failure = float(search.archive.failure)
    cells = int(np.prod(grid.dims))
    failures = sum(1 for t in elites.values() if t.values[0] >= failure)
    return {"archive_cells": cells, "archive_filled": len(elites), "archive_failure_cells": failures,
            "archive_coverage": failures / cells, "archive_qd_score": float(sum(t.values[0] for t in elites.values()))}


def rerun_command(trial: FrozenTrial) -> str:
    from garage_exp.report.trials import rerun_overrides

    return " ".join(["python -m garage_exp", *map(shlex.quote, rerun_overrides(trial))])


def archive_table(trials: list[FrozenTrial], search) -> pd.DataFrame:
    """archive.csv: one row per filled cell (its elite): the cell, each descriptor's measured value, the
    difficulty, whether it is a hard-and-fair failure, the trial, its parameters and the command that reruns it."""
    grid = Grid(search.descriptors)
    rows = []
    for cell, trial in sorted(elite_trials(trials, grid).items()):
        measured = trial.user_attrs["descriptors"]
        rows.append({"cell": grid.name(cell), **{d.source: measured[d.source] for d in grid.descriptors},
                     "difficulty": round(trial.values[0], 6),
                     "failure": trial.values[0] >= float(search.archive.failure), "trial": trial.number,
                     **{f"param.{k}": v for k, v in trial.params.items()}, "rerun": rerun_command(trial)})
    columns = ["cell", *[d.source for d in grid.descriptors], "difficulty", "failure", "trial"]
    return pd.DataFrame(rows, columns=None if rows else [*columns, "rerun"])


def heatmap(trials: list[FrozenTrial], search, path: Path) -> Path:
    """Difficulty per cell: each cell's elite's, a failure cell's value in bold (draw_cells)."""
    grid = Grid(search.descriptors)
    failure = float(search.archive.failure)
    numbers = summary(trials, search)
    values = {cell: trial.values[0] for cell, trial in elite_trials(trials, grid).items()}
    title = (f"difficulty of each cell's elite ({numbers['archive_filled']}/{numbers['archive_cells']} cells "
             f"filled, {numbers['archive_failure_cells']} hard-and-fair failures >= {failure:g}, bold; "
             f"QD score {numbers['archive_qd_score']:.2f})")
    return draw_cells(grid, values, path, title, "difficulty", bold_at=failure)


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
    fig, axes = plt.subplots(rows, cols, figsize=(1.5 + 0.75 * max(dims[1], 2) * cols,
                                                  1.0 + (0.45 * dims[0] + 0.9) * rows),
                             squeeze=False, layout="constrained")
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
        ax.set_title(", ".join(f"{grid.descriptors[k + 2].source} {grid.labels(k + 2)[i]}"
                               for k, i in enumerate(panel)) or "all", fontsize=8)
        ax.set_ylabel(str(grid.descriptors[0].source), fontsize=7)
        ax.set_xlabel(str(grid.descriptors[1].source) if len(grid.dims) > 1 else "", fontsize=7)
    fig.suptitle(textwrap.fill(title, int(fig.get_figwidth() * 12)), fontsize=8)  # ~12 characters an inch
    fig.colorbar(image, ax=axes, shrink=0.6, label=label)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write(study: optuna.Study, search, out_dir: Path) -> tuple[list[Path], dict]:
    """archive.csv and archive.png into out_dir, and the archive's numbers; nothing when no complete trial has
    descriptors (another objective, a dry run)."""
    trials = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not any("descriptors" in t.user_attrs for t in trials):
        return [], {}
    out_dir.mkdir(parents=True, exist_ok=True)
    table = archive_table(trials, search)
    table.to_csv(out_dir / "archive.csv", index=False)
    return [out_dir / "archive.csv", heatmap(trials, search, out_dir / "archive.png")], summary(trials, search)


def spread_over_cells(trials: list[FrozenTrial], search) -> list[FrozenTrial]:
    """A suite band's trials, one per cell (the hardest of the band in it), so that a graded suite drawn from
    the archive takes its scenarios from many failure kinds, not one."""
    grid = Grid(search.descriptors)
    kept: dict[tuple[int, ...] | int, FrozenTrial] = {}
    for trial in sorted(trials, key=lambda t: t.number):
        cell = grid.index(trial.user_attrs.get("descriptors") or {})
        key = cell if cell is not None else -trial.number - 1  # a trial without a cell stands alone
        if key not in kept or trial.values[0] > kept[key].values[0]:
            kept[key] = trial
    return list(kept.values())
