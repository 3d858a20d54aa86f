"""Uncertainty and significance for sweep results: bootstrap intervals over independent units (replicates or
trajectories, never frames: frames of one trajectory are not independent), Wilson intervals for a share of
independent trials (episodes, search trials), an ANOVA with effect sizes, and the logistic
recall-against-visibility curve. Plain numbers in, plain tables out (numpy, pandas, SciPy,
statsmodels)."""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np
import pandas as pd

LEVEL = 0.95
RESAMPLES = 2000
ALPHA = 0.05
# CityPersons' visibility bins (Zhang et al., 2017): "reasonable" >= 0.65, "heavy" 0.2-0.65, and the rest.
VISIBILITY_BINS = (("reasonable (>= 0.65)", 0.65, 1.01), ("heavy (0.2-0.65)", 0.2, 0.65), ("< 0.2", 0.0, 0.2))
KITTI_ORDER = ("easy", "moderate", "hard", "ignored")
MIN_SPREAD = 0.3  # the least range of visible fractions a recall curve is fitted over


def mean_ci(values, seed: int = 0) -> tuple[float, float, float]:
    """The mean of independent units and its 95 % percentile-bootstrap interval; (mean, nan, nan) for fewer
    than two units."""
    x = np.asarray(values, dtype=float)
    x = x[~np.isnan(x)]
    if len(x) == 0:
        return math.nan, math.nan, math.nan
    mean = float(x.mean())
    if len(x) < 2:
        return mean, math.nan, math.nan
    if np.ptp(x) == 0:
        return mean, mean, mean
    from scipy.stats import bootstrap

    res = bootstrap((x,), np.mean, confidence_level=LEVEL, n_resamples=RESAMPLES, method="percentile",
                    rng=np.random.default_rng(seed))
    return mean, float(res.confidence_interval.low), float(res.confidence_interval.high)


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson's 95 % interval of a proportion k / n (independent trials): never empty at 0 or n, unlike the
    plain k/n +- z se; (nan, nan) for n = 0."""
    if n == 0:
        return math.nan, math.nan
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def rate_text(k: int, n: int) -> str:
    """A share of independent trials with its Wilson interval, in words: "0.50 (95 % CI 0.09-0.91, 1 of 2)"."""
    if n == 0:
        return "none (0 trials)"
    low, high = wilson(k, n)
    return f"{k / n:.2f} (95 % CI {low:.2f}-{high:.2f}, {k} of {n})"


def rates_differ(k1: int, n1: int, k2: int, n2: int) -> float:
    """Fisher's exact test (two-sided) of k1/n1 against k2/n2: its p-value; nan (no test) when either side is
    empty."""
    if n1 == 0 or n2 == 0:
        return math.nan
    from scipy.stats import fisher_exact

    return float(fisher_exact([[k1, n1 - k1], [k2, n2 - k2]]).pvalue)


def ratio_ci(values, clusters, seed: int = 0) -> tuple[float, float, float, int]:
    """The mean of frame values (a recall, a mean confidence) with a cluster-bootstrap interval: whole clusters
    (trajectories) are resampled, so correlated frames count once. Returns (mean, low, high, clusters)."""
    df = pd.DataFrame({"v": np.asarray(values, dtype=float), "c": list(clusters)}).dropna()
    if df.empty:
        return math.nan, math.nan, math.nan, 0
    g = df.groupby("c", sort=True)["v"].agg(["sum", "count"])
    sums, counts = g["sum"].to_numpy(), g["count"].to_numpy(dtype=float)
    mean = float(sums.sum() / counts.sum())
    if len(g) < 2:
        return mean, math.nan, math.nan, len(g)
    rng = np.random.default_rng(seed)
    weights = rng.multinomial(len(g), np.full(len(g), 1.0 / len(g)), size=RESAMPLES)
    boot = (weights @ sums) / (weights @ counts)
    low, high = np.quantile(boot, [(1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return mean, float(low), float(high), len(g)


def group_cis(obs: pd.DataFrame, by: list[str], responses: list[str]) -> pd.DataFrame:
    """Per group of `by`: n units, and each response's mean with its interval (columns r, r_low, r_high)."""
    rows = []
    for key, g in obs.groupby(by, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(by, key))
        row["n"] = len(g)
        for r in responses:
            row[r], row[f"{r}_low"], row[f"{r}_high"] = mean_ci(g[r])
        rows.append(row)
    cols = [*by, "n", *(f"{r}{s}" for r in responses for s in ("", "_low", "_high"))]
    return pd.DataFrame(rows, columns=cols)


EXACT_FIT = 1e-10  # residual sum of squares below this share of the total: a perfect fit, no error to test against


def untestable(reason: str, units: int) -> pd.DataFrame:
    """An ANOVA that was not run: no rows, and why (the report prints the reason, never a p-value)."""
    df = pd.DataFrame()
    df.attrs.update(untestable=reason, units=units)
    return df


def anova(obs: pd.DataFrame, factors: list[str], response: str, block: str | None = None) -> pd.DataFrame:
    """Main effects and two-way interactions of `factors` on `response` (one row per unit: a cell's replicate):
    a type-II ANOVA of an OLS model (statsmodels), with partial eta squared as the effect size and a
    "significant at 0.05" column. `block`: a blocking factor (the replicate: replicate k shares its draws across
    cells) entered as a main effect only. Interactions are kept only while residual degrees of freedom remain.

    No test is made, and no p-value given, where there is no error to test against: a response that is the same
    in every unit, no residual degrees of freedom, or a model that fits every unit exactly (F would divide by a
    zero residual; statsmodels then says F = 1e30, p = 0). The empty table's `attrs["untestable"]` says which.
    With one unit per cell the residual is the interaction left out of the model: `attrs["note"]` says that the
    test then assumes the factors do not interact."""
    import statsmodels.formula.api as smf
    from statsmodels.stats.anova import anova_lm

    data = obs.dropna(subset=[response]).copy()
    names = {f: f"f{i}" for i, f in enumerate(factors)}
    data = data.rename(columns=names)
    for col in names.values():
        data[col] = data[col].astype(str)
    usable = [names[f] for f in factors if data[names[f]].nunique() > 1]
    if not usable:
        return pd.DataFrame()
    if data[response].nunique() < 2:
        return untestable(f"{response} is {float(data[response].iloc[0]):.3g} in every unit: nothing varies",
                          len(data))
    terms = [f"C({c})" for c in usable]
    if block and block in data and data[block].nunique() > 1:
        terms.append(f"C({block})")
    pairs = [f"C({a}):C({b})" for a, b in itertools.combinations(usable, 2)]
    while True:
        formula = f"{response} ~ " + " + ".join(terms + pairs)
        model = smf.ols(formula, data=data).fit()
        if model.df_resid > 0 or not pairs:
            break
        pairs.pop()  # a saturated model has no error term: drop interactions from the last
    if model.df_resid <= 0:
        return untestable("no residual degrees of freedom (as many model terms as units); run more replicates, "
                          "`replicates=N`", len(data))
    if float(model.ssr) <= EXACT_FIT * float(model.centered_tss):
        return untestable("the model fits every unit exactly (zero residual variance): there is no error to test "
                          "the effects against; run more replicates, `replicates=N`", len(data))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # statsmodels warns on terms it cannot estimate (F nan): said below
        table = anova_lm(model, typ=2)
    back = {v: k.removeprefix("factor.") for k, v in names.items()}
    resid = float(table.loc["Residual", "sum_sq"])
    out = []
    for term, r in table.drop(index="Residual").iterrows():
        label = " x ".join(back.get(part[2:-1], part[2:-1]) for part in term.split(":"))
        ss, f = float(r["sum_sq"]), float(r["F"])
        tested = int(r["df"]) > 0 and math.isfinite(f)  # a term the data cannot estimate has no test
        out.append({"term": label, "df": int(r["df"]), "F": f if tested else math.nan,
                    "p": float(r["PR(>F)"]) if tested else math.nan,
                    "partial_eta2": ss / (ss + resid) if ss + resid > 0 else math.nan})
    df = pd.DataFrame(out)
    df["significant"] = np.where(df.p.isna(), "-", np.where(df.p < ALPHA, "yes", "no"))
    cells = data.groupby(usable).ngroups
    df.attrs["units"] = len(data)
    df.attrs["df_resid"] = int(model.df_resid)
    if cells == len(data):
        df.attrs["note"] = ("one unit per cell: the error term is the interaction the model leaves out, so the test "
                            "assumes the factors do not interact; replicates give it an error of its own")
    return df


def visibility_bin(fraction) -> pd.Series:
    """CityPersons' bin of each visible fraction."""
    f = pd.Series(fraction, dtype=float)
    out = pd.Series(pd.NA, index=f.index, dtype="object")
    for name, lo, hi in VISIBILITY_BINS:
        out[(f >= lo) & (f < hi)] = name
    return out


def recall_curve(frames: pd.DataFrame, score: str, threshold: float, cluster: str = "trajectory"
                 ) -> dict[str, float]:
    """Detected (score >= threshold) against visible fraction, fitted logistic in the visible fraction
    (statsmodels GLM, errors clustered by trajectory): the visible fraction at which recall crosses 0.5 and its
    95 % interval (delta method). nan where the fit is undefined (one class only, or no slope)."""
    import statsmodels.api as sm

    d = frames[[score, "visible_fraction", cluster]].dropna()
    y = (d[score] >= threshold).astype(float).to_numpy()
    out = {"frames": float(len(d)), "v50": math.nan, "v50_low": math.nan, "v50_high": math.nan,
           "slope": math.nan}
    # A curve needs targets seen over a range of visibility (not only unoccluded ones) and both outcomes.
    if len(d) < 3 or y.min() == y.max() or np.ptp(d.visible_fraction.to_numpy(dtype=float)) < MIN_SPREAD:
        return out
    x = sm.add_constant(d.visible_fraction.to_numpy(dtype=float))
    groups = pd.factorize(d[cluster])[0]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # separation warnings: the interval then says how little is known
            fit = sm.GLM(y, x, family=sm.families.Binomial()).fit(
                cov_type="cluster" if len(set(groups)) > 1 else "nonrobust",
                cov_kwds={"groups": groups} if len(set(groups)) > 1 else None)
    except (np.linalg.LinAlgError, ValueError):
        return out
    b0, b1 = (float(v) for v in fit.params)
    out["slope"] = b1
    if not b1 > 0:
        return out
    v50 = -b0 / b1
    grad = np.array([-1.0 / b1, b0 / b1 ** 2])
    se = float(np.sqrt(max(grad @ np.asarray(fit.cov_params()) @ grad, 0.0)))
    out.update(v50=v50, v50_low=v50 - 1.959964 * se, v50_high=v50 + 1.959964 * se)
    out["fit"] = (b0, b1)  # for the plot
    return out
