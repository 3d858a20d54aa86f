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


# On a space with requirements, the Sobol' points past the sample's size, enqueued after it: a rejected draw is
# redrawn, and the search then takes the sequence's next point, not a random one. Three sizes more: the
# requirements of the wide space accepted about 0.6 of a pilot's draws (docs/loop.md), so 4n points hold n
# accepted ones with a wide margin; past them, the study's own sampler would draw (the report counts those).
SPARE = 3


def requires(cfg) -> bool:
    """Whether the loop's space rejects draws: a shipped space (`space=NAME`, loop/schema.searched) whose file has
    a `require:` block (the search takes it only from the file, so a space given as params has none)."""
    from garage_exp.loop.schema import space_file

    require = (space_file(cfg) or {}).get("require") or {}
    return any(v is not None for v in require.values())


def draws(space: list[str], n: int, seed: int, method: str = "sobol", rejecting: bool = False) -> list[dict]:
    """The points the held-out study is given, in order: the sample's n (`sample`), and on a space that rejects
    draws (`rejecting`) the same sequence's next SPARE * n, so that the n scenarios that run are the sequence's
    first n accepted points: the same seed gives the same scenarios."""
    return sample(space, n * (1 + SPARE) if rejecting else n, seed, method)


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
    Every sample scenario that ran counts in the denominator (one with no fair frame cannot fail); a draw whose
    actors overlap (infeasible: nothing was rendered) or that the requirements rejected is no scenario."""
    from garage_exp.loop.stats import wilson

    ran = {t.number for t in trials if t.ran and not t.infeasible}
    if not len(frames):  # no scenario rendered a frame: none can fail
        frames = pd.DataFrame({"trial": [], "fair": [], "confidence": []})
    fair = frames[frames.fair.astype(bool) & frames.trial.isin(ran)].groupby("trial").confidence.mean()
    k, n = int((fair < hard_below).sum()), len(ran)
    low, high = wilson(k, n)
    return {"failures": k, "scenarios": n, "per_100": 100.0 * k / n if n else math.nan,
            "low": 100.0 * low, "high": 100.0 * high,
            "failed": sorted(int(t) for t in fair[fair < hard_below].index)}


def parts(held: list[Trial], families: list[str]) -> dict[str, list[Trial]]:
    """The held-out sample on generated garages split by what it holds out (loop/garages.py): `new_seeds` (the
    training families, on seeds no training garage had) and `new_family` (the held-out families, never trained
    on), by each scenario's drawn family; {} when its scenarios draw no family (the shipped plans)."""
    from garage_exp.loop.garages import FAMILY

    if not any(t.params and FAMILY in t.params for t in held):
        return {}
    out: dict[str, list[Trial]] = {"new_seeds": [], "new_family": []}
    for t in held:
        family = (t.params or {}).get(FAMILY)
        out["new_family" if family in families else "new_seeds"].append(t)
    return out


def acceptance(held: list[Trial], enqueued: int) -> dict:
    """What the space's requirements did to the sample: draws, accepted, their share, and how many draws went
    past the enqueued Sobol' points (drawn by the study's own sampler, 0 when the spare points sufficed)."""
    drawn = [t for t in held if t.ran or t.rejected]
    accepted = sum(t.ran for t in drawn)
    return {"draws": len(drawn), "accepted": accepted, "acceptance": accepted / len(drawn) if drawn else math.nan,
            "infeasible": sum(t.infeasible for t in drawn), "scenarios": sum(t.ran and not t.infeasible for t in drawn),
            "past_sobol": max(0, len(drawn) - enqueued)}
