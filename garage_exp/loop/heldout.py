"""The failure rate that matters (issue 39, item 2): a fixed, seeded quasi-random sample of the declared space on a
plan no training frame came from, rendered once, and scored by every detector: hard-and-fair failures per 100
scenarios, with a Wilson interval. Not the search's own count: a search adapts to the detector it searches.

The sample is scipy's scrambled Sobol' (or Halton) sequence over every searched key at once, categorical keys
included (Optuna's QMC sampler draws those at random), mapped onto the space's values: the same seed, space and
size give the same scenarios. The loop enqueues them in the held-out study, which the search then runs as given.
"""

from __future__ import annotations

import math

import numpy as np
import optuna.distributions as od
import pandas as pd

from garage_exp.loop.steps import Trial


def space_params(space: list[str]) -> dict[str, od.BaseDistribution]:
    """The searched keys of the loop's space (override grammar; a `space=NAME` entry: that shipped space's
    params, as the search reads them) and their distributions, in the order given."""
    from garage_exp.search.space import distribution, parse, with_shipped

    return {o.key_or_group: distribution(o) for o in parse(with_shipped(list(space))) if o.is_sweep_override()}


def unit_points(d: int, n: int, seed: int, method: str = "sobol") -> np.ndarray:
    """n points of a scrambled low-discrepancy sequence in [0, 1)^d (seeded)."""
    from scipy.stats import qmc

    if method == "sobol":
        engine = qmc.Sobol(d, scramble=True, seed=seed)
        # Sobol' is balanced at powers of two; the first n of the 2^m points keep its low discrepancy.
        return engine.random_base2(max(0, math.ceil(math.log2(max(n, 1)))))[:n]
    if method == "halton":
        return qmc.Halton(d, scramble=True, seed=seed).random(n)
    raise ValueError(f"{method!r}: sobol | halton")


def value_of(dist: od.BaseDistribution, u: float):
    """The value at quantile u in [0, 1) of a distribution of the space (equal mass per choice or integer)."""
    if isinstance(dist, od.CategoricalDistribution):
        return dist.choices[min(int(u * len(dist.choices)), len(dist.choices) - 1)]
    if isinstance(dist, od.IntDistribution):
        step = dist.step or 1
        count = (dist.high - dist.low) // step + 1
        return int(dist.low + min(int(u * count), count - 1) * step)
    if dist.log:
        return float(math.exp(math.log(dist.low) + u * (math.log(dist.high) - math.log(dist.low))))
    return float(dist.low + u * (dist.high - dist.low))


def sample(space: list[str], n: int, seed: int, method: str = "sobol") -> list[dict]:
    """The held-out scenarios: n parameter sets of the space, deterministic for (space, n, seed, method)."""
    params = space_params(space)
    points = unit_points(len(params), n, seed, method)
    return [{name: value_of(dist, float(u)) for (name, dist), u in zip(params.items(), row)} for row in points]


def enqueue(storage: str, study: str, points: list[dict]) -> None:
    """Put the points in the held-out study before its search runs (a study that holds trials already is a resumed
    one: nothing is added). The search asks for enqueued trials first, so its trials are these points in order."""
    from omegaconf import OmegaConf

    from garage_exp.search.schema import SearchConf
    from garage_exp.search.study import open_study

    search = OmegaConf.structured(SearchConf(storage=storage, study=study, sampler="random"))
    s = open_study(search, study, 0)
    if s.get_trials(deepcopy=False):
        return
    for k, p in enumerate(points):
        s.enqueue_trial(p, user_attrs={"heldout": k})


def failures(frames: pd.DataFrame, trials: list[Trial], hard_below: float) -> dict:
    """A detector's hard-and-fair failures on the held-out sample, from its scored frames (evaluate.score_frames):
    a scenario fails when it has fair frames and the detector's mean confidence over them is below `hard_below`.
    Every sample scenario that ran counts in the denominator (one with no fair frame cannot fail)."""
    from garage_exp.loop.stats import wilson

    ran = {t.number for t in trials if t.state in ("COMPLETE", "PRUNED", "FAIL")}
    fair = frames[frames.fair & frames.trial.isin(ran)].groupby("trial").confidence.mean()
    k, n = int((fair < hard_below).sum()), len(ran)
    low, high = wilson(k, n)
    return {"failures": k, "scenarios": n, "per_100": 100.0 * k / n if n else math.nan,
            "low": 100.0 * low, "high": 100.0 * high,
            "failed": sorted(int(t) for t in fair[fair < hard_below].index)}
