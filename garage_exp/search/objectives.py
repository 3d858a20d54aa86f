"""The search's objectives, one entry each: what the study's values are called, which way is harder, and how a
trial's result is put in words.

Everything that names or words an objective reads it from here: the study's directions and metric names
(study.open_study, which stores the names in the study, so that the analysis of a study loaded from its storage
names its columns the same way), the trial line (loop.line), the parent run's `best_<metric>` (sweep.log_on_parent)
and the summary. Names follow the objective that was asked for, never the values a trial happened to return.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Objective:
    name: str  # `search.objective`
    metrics: tuple[str, ...]  # each of the study's values, in order: trials.csv's columns, best_<metrics[0]>
    directions: tuple[str, ...]  # Optuna's "maximize" | "minimize" for each value (the harder end)
    about: str  # what the first value measures, for the docs and `check_search`'s message
    scored: Callable[[list[float], dict], str]  # a complete trial's words, from its values and attributes
    infeasible: Callable[[dict], str]  # a pruned (untestable) trial's words

    @property
    def metric(self) -> str:
        return self.metrics[0]


def _difficulty(values: list[float], attrs: dict) -> str:
    return (f"difficulty {values[0]:.3f} over {attrs['fair_frames']} fair frame(s), visible fraction "
            f"{attrs['visible_fraction']:.2f}")


def _not_visible(attrs: dict) -> str:
    return f"no fairly visible frame (visible fraction {attrs.get('visible_fraction', 0.0):.2f}): infeasible"


def _late(values: list[float], attrs: dict) -> str:
    from garage_exp.results.late import confirmed_text

    return f"lateness {values[0]:.3f} (late {attrs['late']:.2f}, {confirmed_text(attrs.get('detection_distance'))})"


def _slots(values: list[float], attrs: dict) -> str:
    return (f"slot_miss {values[0]:.3f} (slot recall {attrs['slot_recall']:.3f}, {attrs['slot_fair']:.1f} fair "
            "slots a frame)")


OBJECTIVES: dict[str, Objective] = {o.name: o for o in (
    Objective("difficulty", ("difficulty",), ("maximize",),
              "1 - the mean composite confidence over the fairly visible frames", _difficulty, _not_visible),
    Objective("pareto", ("difficulty", "visible_fraction"), ("maximize", "maximize"),
              "difficulty against the target's visible fraction, both maximised", _difficulty, _not_visible),
    # late: how much of the fairly visible approach went by before the target was confirmed (results/late.py)
    Objective("late", ("lateness",), ("maximize",),
              "the share of the fairly visible approach gone by before the target was confirmed", _late,
              lambda attrs: "never fairly visible before the critical distance: infeasible"),
    # slots: 1 - recall of the fair slots (a slot case, docs/slots.md)
    Objective("slots", ("slot_miss",), ("maximize",), "1 - the recall of the fairly visible parking slots", _slots,
              lambda attrs: "no fair slot in any BEV frame: infeasible"),
)}


def objective(name: str) -> Objective:
    """The objective `search.objective` names (check_search has refused unknown names)."""
    return OBJECTIVES[name]
