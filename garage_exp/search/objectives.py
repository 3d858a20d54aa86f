"""The search's objectives, one entry each: what the study's values are called, which way is harder, how a trial
is judged (its values, or infeasible), what a job must be to be judged so, how the pre-screen judges it cheaply,
and how a trial's result is put in words.

Everything that names, judges or words an objective reads it from here: the config check (study.check_search:
known names, a multi-objective sampler for several values, a pre-screen only where the objective has one), the
composed job's check (sweep.check_space: `needs`), the trial's outcome and line (loop.outcome, loop.line), the
pre-screen (prescreen.look: `screen`), the study's directions and metric names (study.open_study, which stores
the names in the study, so that the analysis of a study loaded from its storage, report/search_analysis.py,
names its columns the same way without knowing the objectives), the parent run's `best_<metric>`
(sweep.log_on_parent), the suite's manifest and the summary. Names follow the objective that was asked for,
never the values a trial happened to return.

The trial's own attributes are the objective's too: `attrs` names the job summary's values a trial records beside
its value (the late objective's verdict: late, detection distance, TTC), with their headings in the search report;
the trial loop records them (`recorded`), and the study stores the headings (`shown`) for the report, which reads
them from the study as it reads the value names.

Adding an objective is one `register_objective(Objective(...))` in a module of its own (its judge and words beside
it); the shipped ones are registered below. docs/architecture.md, "Extension points".
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from garage_exp.core.plain import settings
from garage_exp.results.late import LABELS
from garage_exp.results.summary import JobSummary

NOT_VISIBLE = "no fairly visible frame"
# What the pre-screen's judge returns: run the trial in full, or prune it as infeasible or as clearly easy.
FULL, INFEASIBLE, EASY = "", "infeasible", "easy"


@dataclass(frozen=True)
class Objective:
    name: str  # `search.objective`
    metrics: tuple[str, ...]  # each of the study's values, in order: trials.csv's columns, best_<metrics[0]>
    directions: tuple[str, ...]  # Optuna's "maximize" | "minimize" for each value (the harder end)
    # The study's values from a job's summary (results.summary.JobSummary, from run.frames.run_frames) and the
    # trial's attributes so far (which it may add to); None: the trial is untestable, pruned as infeasible.
    judge: Callable[[JobSummary, dict], list[float] | None]
    scored: Callable[[list[float], dict], str]  # a complete trial's words, from its values and attributes
    untestable: str  # why a trial is pruned as infeasible (stored in the study for its report)
    # What the composed job must be for this objective (a driving ego, a slot case on a rig with a BEV): the
    # reason it is not, else None.
    needs: Callable[[object], str | None] = lambda job: None
    # The pre-screen's judge (search/prescreen.py): (frame table, fair mask, case set-up, config, detector
    # level?, attrs) -> FULL | INFEASIBLE | EASY; None: this objective has no cheap look.
    screen: Callable | None = None
    confidence: bool = False  # the first value is 1 - the composite confidence (the suite's confidence column)
    # The gym's adversary (garage_exp/gym): its name for this objective (`gym.objective`; "": the gym cannot be
    # rewarded for it) and the episode verdict's key it rewards (gym/reward.judge). An episode's value is its
    # `metric`.
    gym: str = ""
    verdict: str = ""
    # The objective judges only what happens before the ego's critical distance (late detection): the gym's dense
    # reward counts fair frames before it, and an episode is decided once the target is confirmed or passed.
    until_critical: bool = False
    # The job summary's values a trial records as attributes whenever its summary holds them, whatever objective
    # the search asked for (a difficulty search on a case that drives the ego records the late verdict too), each
    # with its heading in the search report's tables (None: recorded, not shown).
    attrs: dict[str, str | None] = field(default_factory=dict)

    @property
    def metric(self) -> str:
        return self.metrics[0]

    @property
    def multi(self) -> bool:
        return len(self.directions) > 1

    def infeasible(self, attrs: dict) -> str:
        """A pruned (untestable) trial's words."""
        if self.untestable == NOT_VISIBLE:
            return f"{NOT_VISIBLE} (visible fraction {attrs.get('visible_fraction', 0.0):.2f}): infeasible"
        return f"{self.untestable}: infeasible"


def num(value) -> float | None:
    """A summary's number, None when it is missing or NaN."""
    return None if value is None or (isinstance(value, float) and math.isnan(value)) else float(value)


# --- difficulty (and pareto): 1 - the mean composite confidence over the fairly visible frames (results/table.py)

def _judge_difficulty(result: JobSummary, attrs: dict) -> list[float] | None:
    difficulty = num(result.fair_difficulty)
    return None if attrs["fair_frames"] == 0 or difficulty is None else [difficulty]


def _judge_pareto(result: JobSummary, attrs: dict) -> list[float] | None:
    values = _judge_difficulty(result, attrs)
    return None if values is None else [*values, attrs["visible_fraction"]]


def _difficulty(values: list[float], attrs: dict) -> str:
    return (f"difficulty {values[0]:.3f} over {attrs['fair_frames']} fair frame(s), visible fraction "
            f"{attrs['visible_fraction']:.2f}")


def _screen_difficulty(table, fair, setup, cfg, detect: bool, attrs: dict) -> str:
    if not fair.any():
        return INFEASIBLE
    if detect:
        difficulty = 1.0 - float(table[fair].composite.mean())
        attrs["prescreen_difficulty"] = difficulty
        if difficulty < float(cfg.search.prescreen.easy):
            return EASY
    return FULL


# --- late: how much of the fairly visible approach went by before the target was confirmed (results/late.py)

def _judge_late(result: JobSummary, attrs: dict) -> list[float] | None:
    lateness = num(result.lateness)
    return None if not result.late_testable or lateness is None else [lateness]


def _late(values: list[float], attrs: dict) -> str:
    from garage_exp.results.late import confirmed_text

    return f"lateness {values[0]:.3f} (late {attrs['late']:.2f}, {confirmed_text(attrs.get('detection_distance'))})"


def _needs_late(job) -> str | None:
    from garage_exp.scenario.build import moves_ego

    job = settings(job)  # the stages below are handed plain data
    if moves_ego(job.case):  # a static ego has no stopping distance to be late for
        return None
    return (f"the late objective needs a case whose motion drives the ego; case {job.case.name} moves "
            f"{job.case.motion.actor or 'nothing'!r} (try case=stepout or case=1)")


def _screen_late(table, fair, setup, cfg, detect: bool, attrs: dict) -> str:
    from garage_exp.results import late

    cfg = settings(cfg)  # the stages below are handed plain data
    per = late.trajectories(table, {s.index: s.time for s in setup.shots}, fair, cfg.ego, cfg.detector.threshold)
    if not per.testable.any():
        return INFEASIBLE
    if detect:
        confirmed = per[per.testable].detection_distance
        margin = late.critical_distance(cfg.ego) + float(cfg.search.prescreen.slack)
        attrs["prescreen_detection_distance"] = float(confirmed.min()) if confirmed.notna().all() else math.nan
        if confirmed.notna().all() and (confirmed >= margin).all():
            return EASY
    return FULL


# --- slots: 1 - recall of the fair slots (a slot case, docs/slots.md)

def _judge_slots(result: JobSummary, attrs: dict) -> list[float] | None:
    recall, fair = num(result.metric("slot_recall")), num(result.metric("slot_truth_fair"))
    attrs.update({"slot_recall": recall, "slot_fair": fair, "slot_precision": num(result.metric("slot_precision"))})
    return None if recall is None or not fair else [1.0 - recall]


def _slots(values: list[float], attrs: dict) -> str:
    return (f"slot_miss {values[0]:.3f} (slot recall {attrs['slot_recall']:.3f}, {attrs['slot_fair']:.1f} fair "
            "slots a frame)")


def _needs_slots(job) -> str | None:
    from garage_exp.scene.lenses import rig_has

    job = settings(job)  # the stages below are handed plain data
    if job.case.get("slots", False) and rig_has(job.camera, "bev"):
        return None
    return (f"the slots objective needs a slot case on a fisheye rig (case=slots camera=fisheye4), not case "
            f"{job.case.name} on rig {job.camera.name}")


OBJECTIVES: dict[str, Objective] = {}


def register_objective(goal: Objective) -> Objective:
    """Register an objective under its name (`search.objective`), replacing one of that name."""
    OBJECTIVES[goal.name] = goal
    return goal


for _goal in (
    Objective("difficulty", ("difficulty",), ("maximize",), _judge_difficulty, _difficulty, NOT_VISIBLE,
              screen=_screen_difficulty, confidence=True, gym="hard", verdict="hard_fair"),
    # the difficulty against the target's visible fraction, both maximised
    Objective("pareto", ("difficulty", "visible_fraction"), ("maximize", "maximize"), _judge_pareto, _difficulty,
              NOT_VISIBLE, confidence=True),
    Objective("late", ("lateness",), ("maximize",), _judge_late, _late,
              "never fairly visible before the critical distance", needs=_needs_late, screen=_screen_late,
              gym="late", verdict="late", until_critical=True,
              attrs={"late": "late", "lateness": None, "detection_distance": LABELS["detection_distance"],
                     "ttc_at_detection": LABELS["ttc_at_detection"], "fair_difficulty": None}),
    Objective("slots", ("slot_miss",), ("maximize",), _judge_slots, _slots, "no fair slot in any BEV frame",
              needs=_needs_slots),
):
    register_objective(_goal)


def objective(name: str) -> Objective:
    """The objective `search.objective` names (check_search has refused unknown names)."""
    return OBJECTIVES[name]


def recorded(result: JobSummary) -> dict:
    """The registered objectives' `attrs` that a job's summary holds, as a trial records them."""
    values = result.as_dict(trial=False)
    return {k: num(values[k]) for goal in OBJECTIVES.values() for k in goal.attrs if k in values}


def shown() -> dict[str, str]:
    """Each recorded attribute the search report shows, by name, with its heading (stored in the study)."""
    return {k: words for goal in OBJECTIVES.values() for k, words in goal.attrs.items() if words}


def gym_objectives() -> dict[str, Objective]:
    """The objectives the gym's adversary can be rewarded for, by the gym's name for each (`gym.objective`)."""
    return {o.gym: o for o in OBJECTIVES.values() if o.gym}
