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

NOT_VISIBLE = "no fairly visible frame"


@dataclass(frozen=True)
class Objective:
    name: str  # `search.objective`
    metrics: tuple[str, ...]  # each of the study's values, in order: trials.csv's columns, best_<metrics[0]>
    directions: tuple[str, ...]  # Optuna's "maximize" | "minimize" for each value (the harder end)
    scored: Callable[[list[float], dict], str]  # a complete trial's words, from its values and attributes
    untestable: str  # why a trial is pruned as infeasible (stored in the study for its report)

    @property
    def metric(self) -> str:
        return self.metrics[0]

    def infeasible(self, attrs: dict) -> str:
        """A pruned (untestable) trial's words."""
        if self.untestable == NOT_VISIBLE:
            return f"{NOT_VISIBLE} (visible fraction {attrs.get('visible_fraction', 0.0):.2f}): infeasible"
        return f"{self.untestable}: infeasible"


def _difficulty(values: list[float], attrs: dict) -> str:
    return (f"difficulty {values[0]:.3f} over {attrs['fair_frames']} fair frame(s), visible fraction "
            f"{attrs['visible_fraction']:.2f}")


def _late(values: list[float], attrs: dict) -> str:
    from garage_exp.results.late import confirmed_text

    return f"lateness {values[0]:.3f} (late {attrs['late']:.2f}, {confirmed_text(attrs.get('detection_distance'))})"


def _slots(values: list[float], attrs: dict) -> str:
    return (f"slot_miss {values[0]:.3f} (slot recall {attrs['slot_recall']:.3f}, {attrs['slot_fair']:.1f} fair "
            "slots a frame)")


OBJECTIVES: dict[str, Objective] = {o.name: o for o in (
    # difficulty: 1 - the mean composite confidence over the fairly visible frames (results/table.py)
    Objective("difficulty", ("difficulty",), ("maximize",), _difficulty, NOT_VISIBLE),
    # pareto: the difficulty against the target's visible fraction, both maximised
    Objective("pareto", ("difficulty", "visible_fraction"), ("maximize", "maximize"), _difficulty, NOT_VISIBLE),
    # late: how much of the fairly visible approach went by before the target was confirmed (results/late.py)
    Objective("late", ("lateness",), ("maximize",), _late, "never fairly visible before the critical distance"),
    # slots: 1 - recall of the fair slots (a slot case, docs/slots.md)
    Objective("slots", ("slot_miss",), ("maximize",), _slots, "no fair slot in any BEV frame"),
)}


def objective(name: str) -> Objective:
    """The objective `search.objective` names (check_search has refused unknown names)."""
    return OBJECTIVES[name]
