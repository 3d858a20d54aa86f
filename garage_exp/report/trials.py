"""A search study's trials as the sweeper left them: the objectives' names, each trial's overrides and the
command that reruns it, one table row per trial, the hardest complete trials.

The sweeper's contract (values: the search objective's, named by the study's user_attr direction_names: difficulty,
lateness, ...; user_attrs: overrides, visible_fraction, fair_frames, frames, recall, confidence, frame, and
"infeasible" on a pruned trial or "error" on a failed one; the objectives' own attributes, named with their
headings by the study's user_attr attr_headings: the late verdict's) is read here and nowhere else in the report.
"""

from __future__ import annotations

import re

import numpy as np
import optuna
import pandas as pd
from optuna.distributions import BaseDistribution
from optuna.trial import FrozenTrial, TrialState

ATTRS = ("visible_fraction", "fair_frames", "frames", "recall", "confidence")
# The search settings a job reads itself: which frames are fair tests (its fair_* metrics and late verdict).
JOB_SEARCH_KEYS = ("search.min_visible=", "search.min_box=", "search.max_truncation=")


def first_value(trial: FrozenTrial) -> float:
    """The trial's first value, the one the study ranks by (difficulty, lateness, slot_miss: whatever the search's
    objective stored as `direction_names`), in single- and multi-objective studies alike."""
    return trial.values[0]


def objective_names(study: optuna.Study) -> list[str]:
    """The study's value names, as the search stored them (search/objectives.py); a study without them was
    made before the search stored names, when the only objectives were difficulty and pareto."""
    names = study.user_attrs.get("direction_names") or study.metric_names
    if names and len(names) == len(study.directions):
        return list(names)
    return ["difficulty", "visible_fraction"][:len(study.directions)] + [
        f"objective_{k}" for k in range(2, len(study.directions))]


def attr_headings(study: optuna.Study) -> dict[str, str]:
    """The objectives' own trial attributes the report shows (a moving ego's late verdict), with their headings, as
    the search stored them (search/objectives.py); none for a study made before it stored them."""
    return dict(study.user_attrs.get("attr_headings") or {})


def untestable(study: optuna.Study) -> str:
    """Why the study's objective prunes a trial as infeasible, as the search stored it."""
    return str(study.user_attrs.get("untestable") or "no fairly visible frame")


def overrides(trial: FrozenTrial) -> list[str]:
    """The trial's override list as the sweeper stored it; its parameters as overrides when it stored none."""
    return list(trial.user_attrs.get("overrides") or [f"{k}={v}" for k, v in trial.params.items()])


def rerun_overrides(trial: FrozenTrial) -> list[str]:
    """The overrides that rerun the scenario as a plain job: without the search's own settings and where it
    logged (`search.*` but the fairness rule the job applies, `tracking.*`), a quoted numeric level unquoted
    (the command line quotes it again)."""
    kept = [o for o in overrides(trial) if o.startswith(JOB_SEARCH_KEYS)
            or not o.startswith(("search.", "tracking.", "hydra."))]
    return [re.sub(r"^([\w.]+)='(\d+)'$", r"\1=\2", o) for o in kept]


def trial_table(study: optuna.Study) -> pd.DataFrame:
    """One row per trial: number, state, the first objective's value (complete trials) in a column named as the
    objective names it (difficulty, lateness, slot_miss: `objective_names`), the contract's user_attrs, each
    parameter in its own column, the overrides, and why a trial was pruned or failed."""
    multi = len(study.directions) > 1
    name = objective_names(study)[0]
    rows = []
    for t in study.get_trials(deepcopy=False):
        done = t.state == TrialState.COMPLETE
        row = {"trial": t.number, "state": t.state.name, name: first_value(t) if done else np.nan}
        for key in (*ATTRS, *attr_headings(study)):
            row[key] = t.user_attrs.get(key, np.nan)
        if multi and done and pd.isna(row["visible_fraction"]):
            row["visible_fraction"] = t.values[1]
        row.update(t.params)
        row["overrides"] = " ".join(overrides(t))
        row["why"] = ("screened as easy by the pre-screen" if t.user_attrs.get("screened") == "easy"
                      else f"infeasible: {t.user_attrs['placement'].split(': ', 2)[-1]}" if t.user_attrs.get("placement")
                      else f"infeasible: {untestable(study)}" if t.user_attrs.get("infeasible")
                      else str(t.user_attrs.get("error", "")))
        row["run_id"] = t.user_attrs.get("run_id", "")
        row["frame"] = t.user_attrs.get("frame", "")
        rows.append(row)
    return pd.DataFrame(rows)


def hardest(study: optuna.Study, top: int) -> list[FrozenTrial]:
    """The top complete trials by the first value (the study's first direction says which end is hard)."""
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    harder_is_higher = study.directions[0] == optuna.study.StudyDirection.MAXIMIZE
    return sorted(done, key=lambda t: (-first_value(t) if harder_is_higher else first_value(t), t.number))[:top]


def distributions(study: optuna.Study) -> dict[str, BaseDistribution]:
    """Each parameter's distribution, as the latest trial that used it declared it."""
    dists: dict[str, BaseDistribution] = {}
    for t in study.get_trials(deepcopy=False):
        dists.update(t.distributions)
    return dists
