"""What makes a study's scenario hard: the parameters' fANOVA importances, and for each parameter of a trial
where its value lies and whether the study's complete trials are harder on that side (Welch's t-test)."""

from __future__ import annotations

import numpy as np
import optuna
import pandas as pd
from optuna.distributions import BaseDistribution, CategoricalDistribution
from optuna.trial import FrozenTrial, TrialState
from scipy.stats import ttest_ind

from garage_exp.report import sensitivity
from garage_exp.report.trials import first_value

FANOVA_SEED = 0  # the importances of one study are the same every time they are computed
THIRDS = ("low third", "middle third", "high third")
ALPHA = 0.05  # a side is called harder only when Welch's t-test tells it from the hardest other side


# fANOVA's cost grows with the trials times the parameters (Optuna's forest of 64 trees grown to one trial a
# leaf, each parameter's marginal over every leaf): 700 complete trials of the wide space's 34 parameters took
# over 10 minutes on this CPU, after a search of 20. A larger study's importances come from a seeded sample of
# this many of its complete trials (said in the report); a smaller one's from all of them, as before.
FANOVA_TRIALS = 300
# Optuna's fANOVA one-hot encodes a choice and averages each parameter's marginal over the product of its columns'
# split midpoints: 2^k for a choice whose k columns the trees split. A search that keeps its offspring near its
# elites (the archive's directed emitter) makes the forest split many of the wide space's 43 target kinds: one
# study's 300 trials ran for over 20 minutes on one tree. A choice of more than this many values is handed to
# fANOVA as its index instead (its importance is still the parameter's: the trees isolate kinds by index ranges).
FANOVA_ONEHOT_MOST = 8


def importances(study: optuna.Study) -> tuple[dict[str, float], str]:
    """fANOVA importances of the parameters for the first value (seeded), or {} and the reason they are missing;
    from a seeded sample of FANOVA_TRIALS complete trials when the study has more (the note says so)."""
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(done) < 2:
        return {}, f"Importances skipped: {len(done)} complete trial(s), fANOVA needs at least 2."
    note = ""
    if len(done) > FANOVA_TRIALS:
        picked = np.random.default_rng(FANOVA_SEED).choice(len(done), FANOVA_TRIALS, replace=False)
        sample = optuna.create_study(directions=study.directions)
        sample.add_trials([done[i] for i in sorted(picked)])
        note = f"Importances from a seeded sample of {FANOVA_TRIALS} of the {len(done)} complete trials."
        study = sample
    study = indexed_choices(study)
    evaluator = optuna.importance.FanovaImportanceEvaluator(seed=FANOVA_SEED)
    try:
        found = optuna.importance.get_param_importances(study, evaluator=evaluator, target=first_value)
    except RuntimeError as exc:  # fANOVA's "zero total variance": every trial equally hard
        return {}, f"Importances skipped: {exc}"
    if not found:
        return {}, "Importances skipped: no parameter was sampled in every complete trial."
    return {k: float(v) for k, v in found.items()}, note


def indexed_choices(study: optuna.Study) -> optuna.Study:
    """The study as fANOVA is handed it: each choice of more than FANOVA_ONEHOT_MOST values as its index (an
    integer parameter of the same name), every other parameter as it is; the study itself when it has none."""
    from optuna.distributions import IntDistribution
    from optuna.trial import create_trial

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    wide = {k for t in done for k, d in t.distributions.items()
            if isinstance(d, CategoricalDistribution) and len(d.choices) > FANOVA_ONEHOT_MOST}
    if not wide:
        return study

    def indexed(t: FrozenTrial) -> FrozenTrial:
        params, dists = dict(t.params), dict(t.distributions)
        for k in wide & set(params):
            choices = dists[k].choices
            params[k], dists[k] = choices.index(params[k]), IntDistribution(0, len(choices) - 1)
        return create_trial(values=t.values, params=params, distributions=dists)

    out = optuna.create_study(directions=study.directions)
    out.add_trials([indexed(t) for t in done])
    return out


def dashboard_importances(study: optuna.Study) -> dict[str, float]:
    """The importances optuna-dashboard shows for the first value (its `_importance.py`, 0.21): Optuna's
    PED-ANOVA evaluator at its defaults (which parameters matter to reach the best 10 % of the complete trials),
    on the value turned to a loss (negated for a maximised one); {} when it has none (too few trials)."""
    import warnings

    from optuna.study import StudyDirection

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(done) < 2:
        return {}
    sign = -1.0 if study.directions[0] == StudyDirection.MAXIMIZE else 1.0
    with warnings.catch_warnings():  # Optuna warns that PED-ANOVA minimises its target: the sign sees to it
        warnings.simplefilter("ignore")
        try:
            found = optuna.importance.get_param_importances(
                study, target=lambda t: sign * t.values[0], evaluator=optuna.importance.PedAnovaImportanceEvaluator())
        except (RuntimeError, ValueError):
            return {}
    return {k: float(v) for k, v in found.items()}


def position(value, dist: BaseDistribution) -> float:
    """Where a numeric value lies in its range, 0 (low end) to 1 (high end); on a log scale for log ranges."""
    return float(np.clip(sensitivity.to_unit(value, dist), 0, 1))


def side(value, dist: BaseDistribution) -> str:
    """The part of the range a value is in: a categorical level, or a third of a numeric range."""
    if isinstance(dist, CategoricalDistribution):
        return str(value)
    return THIRDS[min(int(position(value, dist) * 3), 2)]


def sides(table: pd.DataFrame, param: str, dist: BaseDistribution, name: str = "difficulty") -> dict[str, pd.Series]:
    """The complete trials' values of the objective `name` on each side (third or level) of a parameter."""
    done = table[(table.state == "COMPLETE") & table[param].notna()]
    labels = [side(v, dist) for v in done[param]]
    return {k: g for k, g in done[name].groupby(labels)}


def range_text(dist: BaseDistribution) -> str:
    if isinstance(dist, CategoricalDistribution):
        return "levels " + ", ".join(map(str, dist.choices))
    return f"{dist.low:g} to {dist.high:g}" + (" (log scale)" if getattr(dist, "log", False) else "")


def why_hard(trial: FrozenTrial, table: pd.DataFrame, dists: dict, importance: dict[str, float],
             higher_is_harder: bool = True, name: str = "difficulty") -> list[tuple[str, str, str]]:
    """(parameter, side, sentence) per parameter of the trial, most important first: where its value lies and
    whether the study's complete trials are harder on that side than on the hardest other side (Welch's
    t-test); the sentence says "the harder side" only when they are."""
    lines = []
    for param in sorted(trial.params, key=lambda p: (-importance.get(p, -1), p)):
        dist, value = dists[param], trial.params[param]
        where = side(value, dist)
        groups = sides(table, param, dist, name)
        shown = f"{value:.3g}" if isinstance(value, float) else str(value)
        head = f"`{param}` = {shown}"
        if not isinstance(dist, CategoricalDistribution):
            head += f", {position(value, dist):.0%} of the way from {range_text(dist)}, in the {where}"
        if param in importance:
            head += f" (importance {importance[param]:.2f})"
        mine = groups.get(where, pd.Series(dtype=float))
        others = {k: g for k, g in groups.items() if k != where and len(g) >= 2}
        if len(mine) < 2 or not others:
            lines.append((param, where, f"{head}: too few trials on each side to tell whether this side is harder."))
            continue
        pick = max if higher_is_harder else min
        best = pick(others, key=lambda k: others[k].mean())  # the hardest of the other sides
        rest = others[best]
        there = f"with {param}={best}" if isinstance(dist, CategoricalDistribution) else f"in the {best}"
        if np.ptp(mine) == 0 and np.ptp(rest) == 0:  # no spread: Welch's t is infinite or undefined, p meaningless
            lines.append((param, where, f"{head}: no test (every trial on either side scores the same: {name} "
                                        f"{mine.mean():.2f} there, {len(mine)} trials, against {rest.mean():.2f} "
                                        f"{there}, {len(rest)})."))
            continue
        p = ttest_ind(mine, rest, equal_var=False).pvalue
        harder = mine.mean() >= rest.mean() if higher_is_harder else mine.mean() <= rest.mean()
        verdict = ("no clear harder side" if not p < ALPHA
                   else "the harder side" if harder else "not the harder side")
        lines.append((param, where, f"{head}: {verdict} (p = {p:.2g}): {name} {mine.mean():.2f} on average "
                                    f"there ({len(mine)} trials) against {rest.mean():.2f} {there} ({len(rest)})."))
    return lines


def what_makes_it_hard(reasons: list[tuple[str, str, str]]) -> list[str]:
    """The report's lines for one scenario: a one-line summary, then one bullet per parameter."""
    harder = [f"`{param}` ({where})" for param, where, text in reasons if ": the harder side (" in text]
    summary = ("In short: hard through " + ", ".join(harder) + "." if harder else
               "In short: none of its parameters sits on a side that is clearly harder in this study's data.")
    return ["What makes it hard: " + summary.removeprefix("In short: "), "",
            *(f"- {text}" for _, _, text in reasons), ""]
