"""The adversary's reward, from the project's own arithmetic: late detection (garage_exp/results/late.py: the
critical distance, k-of-n confirmation, the verdict on a trajectory) on the fair frames of the search's rule
(garage_exp/results/table.py `fair_mask`)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from garage_exp.core.errors import GarageError
from garage_exp.results import late
from garage_exp.results.table import fair_mask

HARD = 0.6  # a hard-and-fair episode: difficulty (1 - mean confidence over its fair frames) at least this


def check_ego(ego) -> None:
    """The ego's values; a static ego is refused: it never closes on the target, so no detection can be late
    and no reward can be computed."""
    late.check_ego(ego, moving=False)
    if not float(ego.speed) > 0:
        raise GarageError("a static ego (0 km/h) never closes on the target: there is no late detection to "
                          "reward; give it a speed", "ego.speed")


def critical(ego) -> float:
    return late.critical_distance(ego)


def confirmed_now(hits: list[bool], ego) -> bool:
    return late.confirmed_at(hits, int(ego.k), int(ego.n)) is not None


def fair(row: dict, search) -> bool:
    return bool(fair_mask(pd.DataFrame([row]), search).iloc[0])


def measured(target, score) -> dict:
    """A rendered frame's target (its ground truth, None when not in view) and score, as the frame row's columns
    the fairness rule and the reward read (the step-out env's and a space's draws alike)."""
    return {"distance": round(target.distance, 4) if target else math.nan,
            "visible_fraction": round(target.visible_fraction, 6) if target else 0.0,
            "box_height": (target.full_box[3] - target.full_box[1]) if target and target.full_box else 0,
            "truncation": round(target.truncation, 4) if target else math.nan,
            "composite": round(float(score.composite), 6), "detected": bool(score.detected)}


def episode(frames: list[dict], ego, movers: list[str], critical_m: float, wall_s: float) -> dict:
    """One episode's record: the late verdict on its frames (late.judge: testable only when a perfect detector
    could have confirmed the target in time, so one fair peek earns nothing), its fair difficulty and hard_fair,
    each moved value per frame, and what it cost."""
    t = pd.DataFrame(frames)
    if t.empty:
        verdict = late.judge([], [], [], [], ego)
        fair_conf = np.array([])
    else:
        verdict = late.judge(t.distance.to_numpy(float), t.time.to_numpy(float), t.detected.to_numpy(bool),
                             t.fair.to_numpy(bool), ego)
        fair_conf = t.composite[t.fair].to_numpy(float)
    difficulty = float(1.0 - fair_conf.mean()) if len(fair_conf) else math.nan
    return {"late": bool(verdict.late), "testable": bool(verdict.testable), "lateness": verdict.lateness,
            "detection_distance": verdict.detection_distance, "first_fair_distance": verdict.first_fair_distance,
            "critical_distance": critical_m, "fair_frames": int(len(fair_conf)), "difficulty": difficulty,
            "hard_fair": bool(len(fair_conf) and difficulty >= HARD), "renders": int(len(t)), "wall_s": wall_s,
            "ego": [float(v) for v in t.ego] if len(t) else [],
            "values": {name: [float(v) for v in t[name]] for name in movers} if len(t) else {},
            "confidence": [float(v) for v in t.composite] if len(t) else []}
