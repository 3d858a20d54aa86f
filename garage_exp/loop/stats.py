"""The loop's statistics, from the field's libraries: Wilson intervals of failure rates (results.stats, the
project's one), paired comparisons by training seed (scipy's t-test) with Holm's correction over every
comparison reported (statsmodels' multipletests), and power: how many seeds and held-out scenarios make a
difference in failure rate detectable (statsmodels' TTestPower and NormalIndPower), from a pilot's variance.
Paired by held-out scenario (every detector scores the same frames): McNemar's exact test (statsmodels),
Newcombe's paired interval of the difference, and McNemar's power from a pilot's discordant share (Connor's).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from garage_exp.results.stats import wilson  # the project's one Wilson interval (the loop's failure rates too)


def t_interval(values, alpha: float = 0.05) -> tuple[float, float, float]:
    """(mean, low, high): Student's t interval of the mean; one value has no interval (NaN ends)."""
    from scipy import stats

    v = np.asarray([x for x in values if x == x], dtype=float)
    if len(v) == 0:
        return math.nan, math.nan, math.nan
    mean = float(v.mean())
    if len(v) < 2:
        return mean, math.nan, math.nan
    half = float(stats.t.ppf(1 - alpha / 2, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))
    return mean, mean - half, mean + half


def paired(a: dict[int, float], b: dict[int, float] | float) -> dict:
    """a - b paired by seed (b a number: a detector every seed shares, such as D0): mean, t interval, the two-sided
    p-value of a one-sample t-test on the differences (NaN with fewer than two seeds or no spread), seeds."""
    from scipy import stats

    seeds = sorted(a) if not isinstance(b, dict) else sorted(set(a) & set(b))
    diffs = np.asarray([a[s] - (b[s] if isinstance(b, dict) else b) for s in seeds], dtype=float)
    diffs = diffs[~np.isnan(diffs)]
    mean, low, high = t_interval(diffs)
    p = math.nan
    # No spread (the same difference every seed): t is infinite or 0/0, so there is no test and no p-value
    # (issue 42, item 8: never print one that was not computed); the table says "no test".
    if len(diffs) >= 2 and np.ptp(diffs) > 0:
        p = float(stats.ttest_1samp(diffs, 0.0).pvalue)
    return {"diff": mean, "low": low, "high": high, "p": p, "seeds": int(len(diffs))}


def holm(pvalues, alpha: float = 0.05) -> tuple[list[bool], list[float]]:
    """Holm's step-down correction over a family of p-values (NaN ones are left out and stay NaN, not rejected)."""
    from statsmodels.stats.multitest import multipletests

    p = np.asarray(pvalues, dtype=float)
    ok = ~np.isnan(p)
    reject = np.zeros(len(p), dtype=bool)
    adjusted = np.full(len(p), math.nan)
    if ok.any():
        r, adj, _, _ = multipletests(p[ok], alpha=alpha, method="holm")
        reject[ok], adjusted[ok] = r, adj
    return [bool(x) for x in reject], [float(x) for x in adjusted]


def compare(rows: list[dict], alpha: float = 0.05) -> pd.DataFrame:
    """The comparisons reported (each a `paired` dict plus its names), Holm-corrected as one family."""
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    table["reject_holm"], table["p_holm"] = holm(table.p.to_numpy(), alpha)
    return table


def seeds_needed(sd_diff: float, delta: float = 0.05, alpha: float = 0.05, power: float = 0.8) -> float:
    """Training seeds (pairs) for a paired t-test to detect a mean difference `delta` with standard deviation
    `sd_diff` of the per-seed differences (a pilot's), two-sided."""
    from statsmodels.stats.power import TTestPower

    if not sd_diff > 0:
        return 2.0
    import warnings

    from statsmodels.tools.sm_exceptions import ConvergenceWarning

    effect = delta / sd_diff
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)  # handled below
        n = float(TTestPower().solve_power(effect_size=effect, alpha=alpha, power=power, alternative="two-sided"))
    if n != n:  # statsmodels' root finder fails past an effect of about 10 (seeds that all agree): two pairs, the
        return 2.0 if effect > 1 else math.inf  # fewest a paired t-test takes (a two-seed run's report crashed here)
    return n


def scenarios_needed(p1: float, p2: float, alpha: float = 0.05, power: float = 0.8) -> float:
    """Held-out scenarios per detector to tell failure rates p1 and p2 apart (two independent proportions,
    Cohen's h; the same scenarios for both detectors only need fewer)."""
    from statsmodels.stats.power import NormalIndPower
    from statsmodels.stats.proportion import proportion_effectsize

    h = abs(float(proportion_effectsize(p1, p2)))
    if h == 0:
        return math.inf
    return float(NormalIndPower().solve_power(effect_size=h, alpha=alpha, power=power, ratio=1.0,
                                              alternative="two-sided"))


def scenarios_for(rate: float, relative: float = 0.2, comparisons: int = 1, alpha: float = 0.05,
                  power: float = 0.8) -> int:
    """Held-out scenarios per detector that detect a failure rate `relative` lower than `rate` (a pilot's: 0.3 and
    0.2 ask 0.3 against 0.24), two-sided, at Holm's first step over `comparisons` tests (alpha / comparisons: the
    smallest p-value of the family must clear it), with this power (two independent proportions, Cohen's h: the
    detectors score the same scenarios, so this is an upper bound)."""
    if not 0 < rate < 1 or not 0 < relative < 1:
        raise ValueError(f"a failure rate {rate} and a relative difference {relative} in (0, 1)")
    return math.ceil(scenarios_needed(rate, rate * (1 - relative), alpha / max(1, comparisons), power))


# Paired by held-out scenario (issue 50): every detector scores the same rendered frames, so each held-out scenario
# is one pair of outcomes (failed or not by detector a, by detector b). Only the discordant scenarios carry
# evidence about the difference; the concordant ones (both failed, neither) are the same draw for both.
Z95 = 1.959963984540054  # norm.ppf(0.975), as statsmodels' intervals use it (the Wilson default rounds it)

def newcombe_paired(both: int, a_only: int, b_only: int, neither: int, z: float = Z95) -> tuple[float, float]:
    """Newcombe's (1998) method 10, the hybrid score interval of the paired difference of proportions
    (a's rate - b's rate) from the 2x2 table of pairs: each margin's Wilson interval, combined with the pairs'
    phi correlation. Fagerland, Lydersen and Laake (2014) recommend it for paired proportions: closed-form (no
    seed), inside [-1, 1], never empty with no discordant pair, and built on the Wilson interval the loop already
    reports. (nan, nan) with no pairs."""
    n = both + a_only + b_only + neither
    if n == 0:
        return math.nan, math.nan
    p1, p2 = (both + a_only) / n, (both + b_only) / n
    (l1, u1), (l2, u2) = wilson(both + a_only, n, z), wilson(both + b_only, n, z)
    margins = (both + a_only) * (b_only + neither) * (both + b_only) * (a_only + neither)
    phi = (both * neither - a_only * b_only) / math.sqrt(margins) if margins else 0.0
    delta = p1 - p2
    down = (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2
    up = (u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2
    return max(-1.0, delta - math.sqrt(max(0.0, down))), min(1.0, delta + math.sqrt(max(0.0, up)))


def paired_scenarios(a_failed, b_failed, scenarios: int) -> dict:
    """Detectors a and b on the same `scenarios` held-out scenarios, `a_failed` and `b_failed` the ones each
    failed (heldout.failures' `failed`): the 2x2 table of pairs, both failure rates, their difference a - b with
    Newcombe's paired interval (newcombe_paired), the relative difference (a - b) / b, and McNemar's exact test
    (statsmodels; the two-sided binomial test of the discordant pairs: p = 1 with none)."""
    from statsmodels.stats.contingency_tables import mcnemar

    a, b = {int(x) for x in a_failed}, {int(x) for x in b_failed}
    both, a_only, b_only = len(a & b), len(a - b), len(b - a)
    neither = scenarios - both - a_only - b_only
    if scenarios <= 0 or neither < 0:
        raise ValueError(f"{len(a | b)} failed scenarios of {scenarios}: not the same held-out sample")
    rate_a, rate_b = (both + a_only) / scenarios, (both + b_only) / scenarios
    low, high = newcombe_paired(both, a_only, b_only, neither)
    p = float(mcnemar([[both, a_only], [b_only, neither]], exact=True).pvalue)
    return {"scenarios": scenarios, "both": both, "a_only": a_only, "b_only": b_only, "neither": neither,
            "a_per_100": 100 * rate_a, "b_per_100": 100 * rate_b, "diff": 100 * (rate_a - rate_b),
            "low": 100 * low, "high": 100 * high,
            "relative": (rate_a - rate_b) / rate_b if rate_b > 0 else math.nan, "p": p}


def scenarios_for_paired(rate: float, discordant: float, relative: float = 0.2, comparisons: int = 1,
                         alpha: float = 0.05, power: float = 0.8) -> int:
    """Held-out scenarios (pairs) that McNemar's test needs to detect a failure rate `relative` lower than `rate`
    when both detectors score the same scenarios and a pilot's pair of detectors disagreed on a share `discordant`
    of them (Connor 1987: n = (z_a sqrt(psi) + z_b sqrt(psi - d^2))^2 / d^2, psi the discordant share, d the
    difference), two-sided at Holm's first step over `comparisons`. Fewer than scenarios_for's independent
    samples when the detectors agree on most scenarios; a discordant share below the difference is impossible."""
    from scipy.stats import norm

    d = rate * relative
    if not 0 < rate < 1 or not 0 < relative < 1 or not d <= discordant <= 1:
        raise ValueError(f"a failure rate {rate}, a relative difference {relative} and a discordant share "
                         f"{discordant} (at least {d:.3f}) in (0, 1)")
    za, zb = norm.ppf(1 - alpha / max(1, comparisons) / 2), norm.ppf(power)
    return math.ceil((za * math.sqrt(discordant) + zb * math.sqrt(discordant - d * d)) ** 2 / (d * d))
