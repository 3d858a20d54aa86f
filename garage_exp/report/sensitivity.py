"""Global sensitivity of the difficulty to the continuous factors: Sobol' first-order (S1) and total-order (ST)
indices with 95 % intervals, by SALib.

Two ways to the same table:
- `search.sampler=saltelli`: the sweeper enqueues `saltelli_design(space, n, seed)` (Saltelli's extension of a
  Sobol' sequence, N (D + 2) points for D factors: first and total order only, which is what the issue asks and
  half the second-order design's cost) and `sobol_indices` analyses the renders directly (method "saltelli").
- any other study: a Gaussian-process surrogate is fitted on the complete trials and Saltelli's estimator is run
  on it (method "surrogate"). Its intervals add the surrogate's own uncertainty (posterior draws) to SALib's
  bootstrap interval, so a study too small to pin the function down says so by wide intervals.
Categorical factors (an occluder's size, a colour) are not in the design; in the surrogate they are averaged
over as the study sampled them.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import optuna
import pandas as pd
from optuna.distributions import BaseDistribution, FloatDistribution, IntDistribution
from optuna.trial import TrialState
from scipy.stats import kstest

from garage_exp.core.errors import GarageError

COLUMNS = ["factor", "S1", "S1_conf", "ST", "ST_conf", "method"]
CROWDED = 0.2  # a KS distance above this: the trials do not cover a factor's range evenly
MIN_TRIALS = 10  # below this a surrogate over even one factor is a guess
MAX_FIT = 400  # a GP fit grows as n^3: a larger study is subsampled (seeded) for the surrogate
SURROGATE_N = 1024  # Saltelli base sample on the surrogate: cheap, so large enough for small MC error
DRAW_N, DRAWS = 128, 16  # posterior draws of the GP on a smaller design, for the surrogate's own uncertainty


def continuous(space: dict[str, BaseDistribution]) -> dict[str, BaseDistribution]:
    return {k: d for k, d in space.items() if isinstance(d, (FloatDistribution, IntDistribution))}


def to_unit(value: float, dist: BaseDistribution) -> float:
    """A value's place in its range, 0 to 1 (log ranges on a log scale): the design's and surrogate's axes."""
    lo, hi, v = float(dist.low), float(dist.high), float(value)
    if dist.log:
        lo, hi, v = np.log(lo), np.log(hi), np.log(v)
    return 0.5 if hi == lo else (v - lo) / (hi - lo)


def from_unit(u: float, dist: BaseDistribution) -> float | int:
    """The value at place u of the range, on the distribution's step (ints rounded) and inside its bounds."""
    lo, hi = float(dist.low), float(dist.high)
    v = float(np.exp(np.log(lo) + u * (np.log(hi) - np.log(lo)))) if dist.log else lo + u * (hi - lo)
    step = getattr(dist, "step", None)
    if step:
        v = lo + round((v - lo) / step) * step
    v = min(max(v, lo), hi)
    return int(round(v)) if isinstance(dist, IntDistribution) else v


def problem(names: list[str]) -> dict:
    return {"num_vars": len(names), "names": names, "bounds": [[0.0, 1.0]] * len(names)}


def unit_design(names: list[str], n: int, seed: int) -> np.ndarray:
    from SALib.sample import sobol as sobol_sample

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # SALib warns about a non-power-of-2 n; saltelli_design checks it itself
        return sobol_sample.sample(problem(names), n, calc_second_order=False, seed=seed)


def saltelli_design(space: dict[str, BaseDistribution], n: int, seed: int) -> list[dict]:
    """The Saltelli points for the continuous distributions of the space, as parameter dicts, in design order
    (point k is enqueued with user_attrs {"saltelli": k}); n (the base sample) must be a power of 2."""
    factors = continuous(space)
    if not factors:
        raise GarageError("no continuous factor (interval or range) in the search space", "search.sampler=saltelli")
    if n < 2 or n & (n - 1):
        raise GarageError(f"the Saltelli base sample must be a power of 2 (Sobol' sequence), not {n}",
                          "search.sampler=saltelli")
    names = list(factors)
    return [{k: from_unit(u, factors[k]) for k, u in zip(names, row)} for row in unit_design(names, n, seed)]


def analyse_design(names: list[str], y: np.ndarray, seed: int) -> pd.DataFrame:
    from SALib.analyze import sobol as sobol_analyze

    res = sobol_analyze.analyze(problem(names), y, calc_second_order=False, conf_level=0.95, seed=seed)
    return pd.DataFrame({"factor": names, "S1": res["S1"], "S1_conf": res["S1_conf"], "ST": res["ST"],
                         "ST_conf": res["ST_conf"]})


def saltelli_outputs(study: optuna.Study) -> tuple[list[str], np.ndarray] | None:
    """The design's factors and outputs in design order when every point of a complete Saltelli design was
    rendered and completed; None otherwise."""
    trials = study.get_trials(deepcopy=False)
    marked = [t for t in trials if "saltelli" in t.user_attrs]
    done = {t.user_attrs["saltelli"]: t for t in marked if t.state == TrialState.COMPLETE}
    if not marked or len(done) != len(marked):
        return None
    names = [k for k, d in marked[0].distributions.items() if isinstance(d, (FloatDistribution, IntDistribution))]
    size = max(done) + 1
    if not names or sorted(done) != list(range(size)) or size % (len(names) + 2):
        return None
    return names, np.array([done[k].values[0] for k in range(size)], dtype=float)


def complete_data(study: optuna.Study) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The continuous factors every complete trial has, their places in range (rows) and the difficulties."""
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(done) < MIN_TRIALS:
        raise GarageError(f"{len(done)} complete trials, a surrogate needs at least {MIN_TRIALS}")
    common = set.intersection(*(set(t.params) for t in done))
    dists = {k: d for k, d in done[-1].distributions.items() if k in common}
    names = sorted(continuous(dists))
    if not names:
        raise GarageError("no continuous factor was sampled in every complete trial")
    x = np.array([[to_unit(t.params[k], dists[k]) for k in names] for t in done])
    return names, x, np.array([t.values[0] for t in done], dtype=float)


def fit_gp(x: np.ndarray, y: np.ndarray, seed: int):
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    # ARD Matern: one length scale per factor, so an inert factor gets a long one; the white kernel takes the
    # render-to-render noise (replicates, detector jitter) instead of bending the fit through it
    kernel = (ConstantKernel(1.0) * Matern(length_scale=[0.5] * x.shape[1], length_scale_bounds=(1e-2, 1e3), nu=2.5)
              + WhiteKernel(1e-2, (1e-6, 1.0)))
    gp = GaussianProcessRegressor(kernel, normalize_y=True, n_restarts_optimizer=1, random_state=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return gp.fit(x, y)


def posterior_draws(gp, x: np.ndarray, k: int, seed: int) -> np.ndarray:
    """k joint draws of the fitted GP at the rows of x (columns), through a Cholesky factor: sklearn's
    sample_y takes an SVD, several times slower on a busy machine. The jitter keeps the factor defined."""
    from scipy.linalg import cholesky

    mean, cov = gp.predict(x, return_cov=True)
    jitter = 1e-10 * max(float(np.trace(cov)) / len(x), 1e-12)
    for _ in range(6):
        try:
            low = cholesky(cov + jitter * np.eye(len(x)), lower=True)
            break
        except np.linalg.LinAlgError:
            jitter *= 100
    else:
        raise GarageError("the surrogate's posterior is degenerate (no Cholesky factor)")
    return mean[:, None] + low @ np.random.default_rng(seed).standard_normal((len(x), k))


def surrogate_indices(study: optuna.Study, seed: int) -> pd.DataFrame:
    names, x, y = complete_data(study)
    if np.ptp(y) == 0:
        raise GarageError(f"all {len(y)} complete trials are equally hard: nothing to attribute")
    if len(y) > MAX_FIT:
        keep = np.random.default_rng(seed).choice(len(y), MAX_FIT, replace=False)
        x, y = x[keep], y[keep]
    gp = fit_gp(x, y, seed)
    table = analyse_design(names, gp.predict(unit_design(names, SURROGATE_N, seed)), seed)
    # the surrogate's uncertainty: the indices over posterior draws of the fitted GP (a smaller design, since a
    # joint draw costs n^3), added to SALib's Monte Carlo interval
    draws = posterior_draws(gp, unit_design(names, DRAW_N, seed + 1), DRAWS, seed)
    per_draw = [analyse_design(names, draws[:, j], seed) for j in range(DRAWS)]
    for col in ("S1", "ST"):
        spread = 1.96 * np.std([d[col].to_numpy() for d in per_draw], axis=0)
        table[f"{col}_conf"] = np.hypot(table[f"{col}_conf"].to_numpy(), spread)
    table["method"] = "surrogate"
    table["trials"] = len(y)
    # how far the trials are from covering each range evenly (Kolmogorov-Smirnov distance to uniform, the worst
    # factor): a TPE study crowds its trials where it is hard, and the surrogate is then a guess elsewhere
    table["crowding"] = max(kstest(x[:, j], "uniform").statistic for j in range(x.shape[1]))
    table["noise_share"] = float(gp.kernel_.k2.noise_level)  # of the normalised difficulty's variance
    return table


def sobol_indices(study: optuna.Study, seed: int = 0) -> pd.DataFrame:
    """Sobol' S1 and ST with 95 % half-widths for each continuous factor, largest total order first: from the
    Saltelli design when the study holds all of it complete, else from a GP surrogate of the complete trials.
    GarageError (one line) when neither is possible."""
    direct = saltelli_outputs(study)
    if direct:
        names, y = direct
        table = analyse_design(names, y, seed)
        table["method"], table["trials"], table["noise_share"], table["crowding"] = "saltelli", len(y), np.nan, 0.0
    else:
        table = surrogate_indices(study, seed)
    return table.sort_values("ST", ascending=False, ignore_index=True)


def method_text(table: pd.DataFrame) -> str:
    """One plain sentence on how the indices were obtained, for the report."""
    n = int(table.trials.iloc[0])
    if table.method.iloc[0] == "saltelli":
        return (f"Sobol' indices from the {n} renders of the Saltelli design (SALib, first and total order, "
                "95 % bootstrap intervals).")
    noise, crowding = float(table.noise_share.iloc[0]), float(table.crowding.iloc[0])
    return (f"Sobol' indices of a Gaussian-process surrogate fitted on {n} complete trials (not a Saltelli "
            f"design: method \"surrogate\"); the fit leaves {noise:.0%} of the difficulty's variance to noise. "
            "Intervals: SALib's bootstrap plus the surrogate's posterior spread. S1: the share of the "
            "difficulty's variance a factor explains alone; ST: with its interactions."
            + (f" The trials crowd part of the ranges (Kolmogorov-Smirnov distance to even coverage "
               f"{crowding:.2f}), as an optimiser's do: the indices hold for the region searched; for the whole "
               "ranges use search.sampler=saltelli (or a random or quasi-random study)." if crowding > CROWDED else ""))


def bar_plot(table: pd.DataFrame, path: Path) -> Path:
    """S1 and ST per factor, side by side, with their 95 % intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pos = np.arange(len(table))
    fig, ax = plt.subplots(figsize=(1.4 * len(table) + 2.5, 3.6), dpi=110)
    ax.bar(pos - 0.2, table.S1, 0.4, yerr=table.S1_conf, capsize=4, label="first order S1", color="tab:blue")
    ax.bar(pos + 0.2, table.ST, 0.4, yerr=table.ST_conf, capsize=4, label="total order ST", color="tab:orange")
    ax.set_xticks(pos, table.factor, rotation=15, ha="right")
    ax.axhline(0, color="black", lw=0.6)
    ax.set_ylabel("share of the difficulty's variance")
    ax.set_title(f"Sobol' indices ({table.method.iloc[0]}, 95 % intervals)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
