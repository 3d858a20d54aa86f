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
The surrogate emitter (search/surrogate.py) chooses among uniform draws and Gaussian offspring the one a forest,
fit on the study's finished trials, expects to add the most failure cells not yet found.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import optuna
import optuna.distributions as od
import pandas as pd
from optuna.trial import FrozenTrial, TrialState

from garage_exp.core.errors import GarageError
from garage_exp.search.descriptors import CATEGORY, DESCRIPTORS, descriptor
from garage_exp.report import archive_cells
# the cells as a study leaves them live in the report (its section and the standalone analysis write them); the
# sampler, the suite and the loop use them from here
from garage_exp.report.archive_cells import Grid, draw_cells, elite_trials  # noqa: F401

log = logging.getLogger("garage_exp")
X_ATTR = "archive:x"  # the normalised point the archive sampler asked (system attr of the trial)
PARENT_ATTR = "archive:parent"  # the elite (trial number) an offspring was mutated from (system attr, curiosity)
EMITTERS = ("gaussian", "iso_line", "sparse", "directed", "surrogate")
PARENTS = ("uniform", "curiosity")
LINE_SIGMA = 0.2  # the iso-line emitter's spread along the line between two elites (ribs' default)
# Curiosity (Cully & Demiris 2018, "Quality and diversity optimization: a unifying modular framework"): an elite
# gains for each offspring that entered the archive and loses for each that did not; parents are drawn in
# proportion to 1 + that score, never under CURIOUS_FLOOR.
CURIOUS_GAIN, CURIOUS_LOSS, CURIOUS_FLOOR = 1.0, 0.5, 0.1
SPARSE_MOST = 3  # the sparse emitter redraws 1 to this many of an elite's factors, keeping every other
# The directed emitter (ArchiveSampler.directed): a descriptor's drivers are the factors whose values its bins
# explain best (eta squared), those within DRIVER_SHARE of the best, at most DRIVERS_MOST; learnt once the study
# holds DIRECTED_MIN trials with a cell (before that, a Gaussian step).
DRIVER_SHARE, DRIVERS_MOST, DIRECTED_MIN = 0.5, 3, 30


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
                 sigma: float = 0.15, parents: str = "uniform", failure: float = 0.6):
        self.params, self.grid, self.seed = dict(params), Grid(descriptors), int(seed)
        self.startup, self.emitter, self.sigma, self.parents = int(startup), emitter, float(sigma), parents
        self.failure = float(failure)
        self._random = optuna.samplers.RandomSampler(seed=seed)
        self._surrogate: tuple[int, object] | None = None  # (the trials it was fit on, the surrogate): surrogate.py

    def infer_relative_search_space(self, study, trial) -> dict:
        return dict(self.params)

    def ask_point(self, trials: list[FrozenTrial], number: int) -> np.ndarray:
        """The normalised point of trial `number`, from the archive of `trials`: uniform for the first
        `startup` trials and while the archive is empty, else the emitter's (seeded by the trial's number)."""
        return self.ask(trials, number)[0]

    def ask(self, trials: list[FrozenTrial], number: int) -> tuple[np.ndarray, int | None]:
        """ask_point's point and the elite it was mutated from (None: uniform, or chosen by ribs). `trials`: the
        study's finished trials (the archive is built from the complete ones; curiosity scores them all)."""
        from ribs.emitters import GaussianEmitter, IsoLineEmitter

        seeds = np.random.SeedSequence([self.seed, number]).generate_state(3)
        d = len(self.params)
        if self.emitter == "surrogate":
            return self.predicted(trials, number, seeds)
        if self.parents == "curiosity":
            cells: dict[int, tuple | None] = {}
            score, elites = replay_archive(trials, self.grid, cells)  # one pass: the elites, scores and cells
            if number < self.startup or not elites:
                return np.random.default_rng(int(seeds[1])).uniform(size=d), None
            driven = drivers(trials, self.grid, self.params, cells) if self.emitter == "directed" else None
            return self.curious(score, list(elites.values()), np.random.default_rng(int(seeds[2])), driven)
        complete = [t for t in trials if t.state == TrialState.COMPLETE]
        archive = ribs_archive(complete, self.grid, self.params, int(seeds[0]))
        if number < self.startup or archive.empty:
            return np.random.default_rng(int(seeds[1])).uniform(size=d), None
        # Unbounded, then folded into the cube (fold): ribs' bounds clip, which piles every step past an end onto
        # the end, so an elite at an end of the space (the last case, the first light) kept most of its offspring
        # in its own cell (the first loop run's Q arm: 6 trials of one cell).
        if self.emitter in ("sparse", "directed"):
            rng = np.random.default_rng(int(seeds[2]))
            x = np.array(archive.data("solution")[rng.integers(len(archive))], float)
            if self.emitter == "sparse":
                return self.sparse(x, rng), None
            return self.directed(x, drivers(complete, self.grid, self.params), rng), None
        if self.emitter == "iso_line":
            emitter = IsoLineEmitter(archive, iso_sigma=self.sigma, line_sigma=LINE_SIGMA, x0=np.full(d, 0.5),
                                     bounds=None, batch_size=1, seed=int(seeds[2]))
        else:
            emitter = GaussianEmitter(archive, sigma=self.sigma, x0=np.full(d, 0.5), bounds=None, batch_size=1,
                                      seed=int(seeds[2]))
        return fold(emitter.ask()[0], self.params), None

    def predicted(self, trials: list[FrozenTrial], number: int, seeds) -> tuple[np.ndarray, int | None]:
        """The surrogate emitter's point (search/surrogate.py): uniform for the first `startup` trials and while
        the archive is empty, a Gaussian step from an elite drawn uniformly until surrogate.MIN_CELLS finished
        trials have a cell, then the candidate the forest expects to add the most failure cells not yet found."""
        from garage_exp.search import surrogate

        d = len(self.params)
        finished = sorted(trials, key=lambda t: t.number)
        elites = sorted(elite_trials([t for t in finished if t.state == TrialState.COMPLETE], self.grid).values(),
                        key=lambda t: t.number)
        rng = np.random.default_rng(int(seeds[2]))
        if number < self.startup or not elites:
            return np.random.default_rng(int(seeds[1])).uniform(size=d), None
        fit = len(finished) // surrogate.REFIT * surrogate.REFIT
        if self._surrogate is None or self._surrogate[0] != fit:  # refit once per REFIT trials, in this process
            x, y = surrogate.rows(finished[:fit], self.grid, self.point, self.failure)
            model = None
            if int(np.sum(y[:, -1] >= 0)) >= surrogate.MIN_CELLS:
                model = surrogate.Surrogate(self.grid.dims, self.seed * 100_003 + fit).fit(x, y)
            self._surrogate = (fit, model)
        if self._surrogate[1] is None:  # too few trials with a cell to learn from
            parent = elites[int(rng.integers(len(elites)))]
            return self.gaussian(self.point(parent), rng), parent.number
        point, parent = surrogate.propose(self._surrogate[1], finished, self.grid, self.failure,
                                          [self.point(e) for e in elites], self.gaussian, rng, d)
        return point, (None if parent is None else elites[parent].number)

    @staticmethod
    def sparse(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The elite `x` with 1 to SPARSE_MOST of its factors redrawn uniformly, the rest kept. On the wide space
        (33 factors) a Gaussian step moves every factor at once, and its offspring found a new failure cell no more
        often than a random draw (docs/search.md, "Measured at 1,500 scenarios a search"): a failure with one or
        two factors changed stays a failure more often, in a cell its parent's neighbours may not hold."""
        x = np.array(x, float)
        moved = rng.choice(len(x), size=min(len(x), int(rng.integers(1, SPARSE_MOST + 1))), replace=False)
        x[moved] = rng.uniform(size=len(moved))
        return x

    def directed(self, x: np.ndarray, driven: list[np.ndarray] | None, rng: np.random.Generator) -> np.ndarray:
        """The elite `x` moved along one descriptor: one axis drawn uniformly, its drivers (drivers()) redrawn
        uniformly, every other factor kept. The sparse emitter's one to three factors drawn blind rarely touched
        what a cell is made of (most of the wide space's 33 factors move no descriptor), so its offspring stayed in
        their parent's cell; a driver's redraw can move the offspring to another bin of that axis (or land in the same
        one) while the rest of what made the parent hard stays. Before the drivers can be learnt (None), a Gaussian
        step."""
        if driven is None:
            return self.gaussian(x, rng)
        x = np.array(x, float)
        moved = driven[int(rng.integers(len(driven)))]
        x[moved] = rng.uniform(size=len(moved))
        return x

    def curious(self, score: dict[int, float], elites: list[FrozenTrial], rng,
                driven: list[np.ndarray] | None = None) -> tuple[np.ndarray, int]:
        """An elite drawn by its curiosity score (curiosity()), mutated by the emitter (gaussian, iso_line, sparse
        or directed; `driven`: the directed emitter's drivers)."""
        weights = np.array([max(CURIOUS_FLOOR, 1.0 + score.get(e.number, 0.0)) for e in elites])
        parent = elites[int(rng.choice(len(elites), p=weights / weights.sum()))]
        x = self.point(parent)
        if self.emitter == "sparse":
            return self.sparse(x, rng), parent.number
        if self.emitter == "directed":
            return self.directed(x, driven, rng), parent.number
        if self.emitter == "iso_line":  # the line's other end: an elite drawn uniformly, as ribs' IsoLineEmitter
            return self.iso_line(x, self.point(elites[int(rng.integers(len(elites)))]), rng), parent.number
        return self.gaussian(x, rng), parent.number

    def point(self, elite: FrozenTrial) -> np.ndarray:
        """The elite's normalised point: the one it was asked at, else its values encoded."""
        x = elite.system_attrs.get(X_ATTR)
        return np.asarray(x, float) if x is not None else encode(elite.params, self.params)

    def iso_line(self, x: np.ndarray, y: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Iso+LineDD (Vassiliades & Mouret 2018), as ribs' IsoLineEmitter steps: `x` plus Gaussian noise of spread
        sigma plus a step of spread LINE_SIGMA along the line to another elite `y`, folded into the cube."""
        return fold(x + rng.normal(0.0, self.sigma, size=len(x)) + rng.normal(0.0, LINE_SIGMA) * (y - x),
                    self.params)

    def gaussian(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """MAP-Elites' step: `x` plus Gaussian noise of spread sigma, folded into the cube (fold)."""
        return fold(x + rng.normal(0.0, self.sigma, size=len(x)), self.params)

    def sample_relative(self, study, trial, search_space) -> dict:
        if not search_space:
            return {}
        finished = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL) \
            if self.parents == "curiosity" or self.emitter == "surrogate" else (TrialState.COMPLETE,)
        x, parent = self.ask(study.get_trials(deepcopy=False, states=finished), trial.number)
        study._storage.set_trial_system_attr(trial._trial_id, X_ATTR, [float(v) for v in x])
        if parent is not None:
            study._storage.set_trial_system_attr(trial._trial_id, PARENT_ATTR, int(parent))
        return decode(x, self.params)

    def sample_independent(self, study, trial, param_name, param_distribution):
        return self._random.sample_independent(study, trial, param_name, param_distribution)


def drivers(trials: list[FrozenTrial], grid: Grid, params: dict,
            cells: dict[int, tuple | None] | None = None) -> list[np.ndarray] | None:
    """Each descriptor's drivers, learnt from the study's complete trials with a cell: the factors whose
    normalised values its bins explain best, by the correlation ratio (eta squared: the share of a factor's
    variance between the axis' bins), those within DRIVER_SHARE of the axis' best, at most DRIVERS_MOST. None until
    DIRECTED_MIN trials have a cell. Stateless, as the archive is. Its weakness (docs/search.md): offspring copy
    their parents' other factors, so a family's shared values line up with its bins and may be learnt as drivers,
    and a choice's index is ordered as its values are listed. On the wide space at 1,500 trials the distance,
    light and camera drivers were the ones a person would name; at a loop generator's 200 the target class was
    once driven by the person's pose and the target's colour. `cells`: the trials' cells by number, as
    replay_archive placed them (those missing are placed here)."""
    rows = []
    for t in trials:
        if t.state != TrialState.COMPLETE or not t.values:
            continue
        cell = cells[t.number] if cells is not None and t.number in cells else \
            grid.index(t.user_attrs.get("descriptors") or {})
        if cell is not None:
            x = t.system_attrs.get(X_ATTR)
            rows.append((np.asarray(x, float) if x is not None else encode(t.params, params), cell))
    if len(rows) < DIRECTED_MIN:
        return None
    x = np.array([r[0] for r in rows])
    cells = np.array([r[1] for r in rows])
    out = []
    for axis in range(cells.shape[1]):
        eta = np.zeros(x.shape[1])
        total = x.var(axis=0)
        for b in np.unique(cells[:, axis]):
            inside = cells[:, axis] == b
            eta += inside.mean() * (x[inside].mean(axis=0) - x.mean(axis=0)) ** 2
        eta = np.divide(eta, total, out=np.zeros_like(eta), where=total > 0)
        if eta.max() <= 0:
            continue  # an axis every trial shares a bin of: nothing to move it by
        ranked = np.argsort(-eta, kind="stable")[:DRIVERS_MOST]
        out.append(ranked[eta[ranked] >= DRIVER_SHARE * eta[ranked[0]]])
    return out or None


def curiosity(trials: list[FrozenTrial], grid: Grid) -> dict[int, float]:
    """Each parent's curiosity score, replayed from the study in trial order: CURIOUS_GAIN for each offspring that
    entered the archive (a cell of its own, or harder than the cell's elite), -CURIOUS_LOSS for each that did not
    (easier, without a cell, infeasible or rejected by the space's requirements). Stateless, as the archive is:
    a resume or another worker computes the same scores from the same storage."""
    return replay_archive(trials, grid)[0]


def replay_archive(trials: list[FrozenTrial], grid: Grid,
                   cells: dict[int, tuple | None] | None = None) -> tuple[dict[int, float], dict]:
    """The study replayed in trial order: each parent's curiosity score and each cell's elite (the same elites as
    elite_trials: a trial replaces one only when strictly harder). `cells`, when given, gets each complete trial's
    cell by number (None: it has none), so that drivers() need not place them again."""
    best: dict[tuple[int, ...], FrozenTrial] = {}
    score: dict[int, float] = {}
    for trial in sorted(trials, key=lambda t: t.number):
        cell = None
        if trial.state == TrialState.COMPLETE and trial.values:
            cell = grid.index(trial.user_attrs.get("descriptors") or {})
            if cells is not None:
                cells[trial.number] = cell
        added = cell is not None and (cell not in best or trial.values[0] > best[cell].values[0])
        if added:
            best[cell] = trial
        parent = trial.system_attrs.get(PARENT_ATTR)
        if parent is not None:
            score[int(parent)] = score.get(int(parent), 0.0) + (CURIOUS_GAIN if added else -CURIOUS_LOSS)
    return score, best


# --- what a study leaves: archive.csv, the heatmap, coverage and QD score (report/archive_cells.py) -------------

def cells_of(search) -> dict:
    """The search's cells as plain data, as the study records them (archive_cells.RECORDED)."""
    from omegaconf import OmegaConf

    descriptors = search.descriptors
    plain = OmegaConf.to_container(descriptors, resolve=True) if OmegaConf.is_config(descriptors) else descriptors
    return {"descriptors": [dict(d) for d in plain], "failure": float(search.archive.failure)}


def record(study: optuna.Study, search) -> None:
    """The study keeps its cells, so that its report (and `python -m garage_exp.report.search_analysis` on it
    later) writes its archive."""
    study.set_user_attr(archive_cells.RECORDED, cells_of(search))


def summary(trials: list[FrozenTrial], search) -> dict:
    return archive_cells.summary(trials, cells_of(search))


def archive_table(trials: list[FrozenTrial], search) -> pd.DataFrame:
    return archive_cells.archive_table(trials, cells_of(search))


def write(study: optuna.Study, search, out_dir: Path) -> tuple[list[Path], dict]:
    return archive_cells.write(study, cells_of(search), out_dir)


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
