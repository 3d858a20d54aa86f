"""A job's summary as a typed record: what `run.frames.run_frames` measured (results.table's summary and fair
summary, results.late's verdict, the slot frames' metrics), read by the search's loop and objectives by name.

`as_dict()` is the flat mapping MLflow logs and JSON takes, key for key and in the order the job has always
logged it: the frame summary (with its breakdowns per label, model, camera and kind), the fair summary, the late
verdict, the slot metrics. A part the job did not measure (no moving ego: no late verdict) is None and left out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace

# Named parts of the flat mapping, in its order; everything else is a breakdown (`label.*`, `model.*`, `camera.*`,
# `kind.*`, the replicates' interval) or, with the `slot_` prefix, a slot metric.
FRAME_KEYS = ("confidence_mean", "confidence_min", "recall", "frames_under_threshold", "visible_fraction_mean",
              "false_positives", "frames", "difficulty")
FAIR_KEYS = ("fair_frames", "fair_confidence", "fair_difficulty", "fair_recall")
LATE_KEYS = ("late", "lateness", "late_trajectories", "late_testable", "detection_distance", "ttc_at_detection",
             "stopping_distance", "critical_distance")
TRIAL_KEYS = ("frame", "run_id", "output_dir")  # a search trial's: its picture, its run and its dir
SLOT_PREFIX = "slot_"


@dataclass(frozen=True)
class JobSummary:
    """One job's summary metrics (see the module's doc); None: not measured by this job."""

    difficulty: float = math.nan  # 1 - the primary camera's mean composite confidence (NaN: a dry run)
    confidence_mean: float | None = None
    confidence_min: float | None = None
    recall: float | None = None
    frames_under_threshold: float | None = None
    visible_fraction_mean: float | None = None
    false_positives: float | None = None
    frames: float | None = None
    # the search's objective (results.table.fair_summary)
    fair_frames: float | None = None
    fair_confidence: float | None = None
    fair_difficulty: float | None = None
    fair_recall: float | None = None
    # seen in time to stop? (results.late.summary; a moving ego only)
    late: float | None = None
    lateness: float | None = None
    late_trajectories: float | None = None
    late_testable: float | None = None
    detection_distance: float | None = None
    ttc_at_detection: float | None = None
    stopping_distance: float | None = None
    critical_distance: float | None = None
    breakdown: Mapping[str, float] = field(default_factory=dict)  # per label, model, camera, kind; replicates
    slots: Mapping[str, float] = field(default_factory=dict)  # the slot frames' `slot_*` metrics
    frame: str | None = None  # a search trial's hardest fair frame (its picture)
    run_id: str | None = None
    output_dir: str | None = None

    @classmethod
    def of(cls, metrics: Mapping[str, float]) -> "JobSummary":
        """The record of a flat mapping (what as_dict gives back, key for key)."""
        named = {f.name for f in fields(cls)} - {"breakdown", "slots"}
        values = {k: v for k, v in metrics.items() if k in named}
        if values.get("frame") is not None:
            values["frame"] = str(values["frame"])
        rest = {k: v for k, v in metrics.items() if k not in named}
        return cls(**values, breakdown={k: v for k, v in rest.items() if not k.startswith(SLOT_PREFIX)},
                   slots={k: v for k, v in rest.items() if k.startswith(SLOT_PREFIX)})

    def with_(self, **changes) -> "JobSummary":
        """A copy with some parts set (a trial's run id and dir, the slot metrics)."""
        return replace(self, **changes)

    def as_dict(self, trial: bool = True) -> dict:
        """The flat mapping (MLflow's metrics, JSON): the measured parts in the job's order; `trial`: with a
        search trial's frame, run id and dir (not metrics)."""
        out = {k: getattr(self, k) for k in FRAME_KEYS if getattr(self, k) is not None}
        out.update(self.breakdown)
        out.update({k: getattr(self, k) for k in (*FAIR_KEYS, *LATE_KEYS) if getattr(self, k) is not None})
        out.update(self.slots)
        if trial:
            out.update({k: getattr(self, k) for k in TRIAL_KEYS if getattr(self, k) is not None})
        return out

    def metric(self, name: str) -> float | None:
        """A metric by its logged name (a breakdown's or a slot metric too); None when not measured."""
        return self.as_dict(trial=False).get(name)
