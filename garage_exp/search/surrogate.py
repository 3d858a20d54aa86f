"""The archive's surrogate emitter (`search.archive.emitter=surrogate`): a draw chosen for the failure kind it is
predicted to find.

Every MAP-Elites step measured on the wide space (Gaussian, iso-line, sparse, directed; uniform or curious parents)
found a failure cell not found before at about the rate a uniform draw does (docs/search.md), because the step
knows nothing of which cells are still empty. Deep surrogate assisted MAP-Elites (Zhang, Fontaine, Hoover and
Nikolaidis 2022; Bhatt et al., "Deep Surrogate Assisted Generation of Environments", NeurIPS 2022) predicts a
candidate's measures and objective before paying for it. This is its small form for a search of failure kinds:
a random forest (scikit-learn's extra trees, one model with one output per descriptor plus one for the verdict)
learns from the study's finished trials where a point of the normalised space lands (its bin on each descriptor)
and whether it fails fairly (-1: rejected, infeasible or without a cell; 0: fair and passed; 1: fair and failed
at `search.archive.failure`). Each ask scores CANDIDATES points, half uniform draws and half Gaussian offspring
of the archive's elites, by the expected number of failure cells not yet found that it would add:

    P(fair and failed | x) * sum over the cells without a failure of  prod_d P(bin_d | x, a cell)

and proposes the best. The bins are treated as independent given the point (most are set by one or two factors:
the target's kind, its distance, the lamps, the camera's height). Stateless between asks as the archive is: the
forest is fit on the study's first k * REFIT finished trials by number (the same for a resume and for every
worker that sees them), kept in the process until k grows, and seeded by k.
"""

from __future__ import annotations

import numpy as np
from optuna.trial import FrozenTrial, TrialState

MIN_CELLS = 50  # finished trials with a cell before the surrogate proposes (before: the archive's Gaussian step)
REFIT = 25  # the forest is refit each time the study holds this many more finished trials
CANDIDATES = 256  # points scored an ask: half uniform, half Gaussian offspring of elites
TREES = 64


def rows(trials: list[FrozenTrial], grid, point, failure: float) -> tuple[np.ndarray, np.ndarray]:
    """The trials as the forest's data: each one's normalised point (`point(trial)`) and its labels, one column per
    descriptor (the bin, -1 without a cell) and the verdict (-1 no cell, 0 passed, 1 failed at `failure`)."""
    x, y = [], []
    for t in trials:
        try:
            at = point(t)
        except KeyError:  # a trial that failed before all its values were drawn
            continue
        cell = None
        if t.state == TrialState.COMPLETE and t.values:
            cell = grid.index(t.user_attrs.get("descriptors") or {})
        if cell is None:
            y.append([-1] * len(grid.dims) + [-1])
        else:
            y.append([*cell, int(t.values[0] >= failure)])
        x.append(at)
    if not x:
        return np.zeros((0, 0)), np.zeros((0, len(grid.dims) + 1), int)
    return np.asarray(x, float), np.asarray(y, int)


class Surrogate:
    """The forest of one fit (`fit`) and the expected new failure cells of candidate points (`expected`)."""

    def __init__(self, dims: list[int], seed: int):
        self.dims, self.seed = list(dims), int(seed)
        self.forest = None

    def fit(self, x: np.ndarray, y: np.ndarray) -> "Surrogate":
        from sklearn.ensemble import ExtraTreesClassifier

        self.forest = ExtraTreesClassifier(n_estimators=TREES, min_samples_leaf=2, random_state=self.seed, n_jobs=1)
        self.forest.fit(x, y)
        return self

    def expected(self, x: np.ndarray, open_cells: np.ndarray) -> np.ndarray:
        """Each point's expected number of failure cells not yet found (`open_cells`: a bool per cell of the grid,
        C order, True where no failure is held)."""
        probs = self.forest.predict_proba(np.asarray(x, float))
        classes = self.forest.classes_
        verdict = dict(zip(classes[-1], probs[-1].T))
        failed = verdict.get(1, np.zeros(len(x)))
        joint = np.ones((len(x), 1))
        for axis, n in enumerate(self.dims):
            p = np.zeros((len(x), n))
            for k, c in enumerate(classes[axis]):
                if c >= 0:
                    p[:, int(c)] = probs[axis][:, k]
            total = p.sum(axis=1, keepdims=True)
            p = np.divide(p, total, out=np.full_like(p, 1.0 / n), where=total > 0)  # the bins, given a cell
            joint = (joint[:, :, None] * p[:, None, :]).reshape(len(x), -1)
        return failed * (joint @ open_cells.astype(float))


def open_cells(trials: list[FrozenTrial], grid, failure: float) -> np.ndarray:
    """A bool per cell of the grid (C order): True where no complete trial failed at `failure`."""
    empty = np.ones(int(np.prod(grid.dims)), bool)
    for t in trials:
        if t.state == TrialState.COMPLETE and t.values and t.values[0] >= failure:
            cell = grid.index(t.user_attrs.get("descriptors") or {})
            if cell is not None:
                empty[np.ravel_multi_index(cell, grid.dims)] = False
    return empty


def propose(model: Surrogate, trials: list[FrozenTrial], grid, failure: float, elites: list[np.ndarray],
            gaussian, rng: np.random.Generator, d: int) -> tuple[np.ndarray, int | None]:
    """The best of CANDIDATES points by `model.expected`, and the index in `elites` of its parent (None: a uniform
    draw). `gaussian(x, rng)`: the archive's Gaussian step."""
    half = CANDIDATES // 2
    parents = rng.integers(len(elites), size=half) if elites else np.zeros(0, int)
    points = [rng.uniform(size=d) for _ in range(CANDIDATES - len(parents))]
    points += [gaussian(elites[int(k)], rng) for k in parents]
    score = model.expected(np.array(points), open_cells(trials, grid, failure))
    best = int(np.argmax(score))
    uniform = CANDIDATES - len(parents)
    return points[best], (None if best < uniform else int(parents[best - uniform]))
