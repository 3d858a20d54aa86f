"""Seen in time to stop? The failure that matters to a parking car, from a job's frame table.

A moving ego at speed v needs v x reaction + v^2 / (2 deceleration) to stop, plus `margin` between the roof
camera and the target's centre: the critical distance. The perception stack *confirms* a target at the frame
that completes k hits (composite confidence >= the threshold) within the last n frames, as a tracker's k-of-n
confirmation does. A trajectory (a variant of one replicate, frames in order) is:

- testable when the detectors confirmed the target in time, or a perfect detector could have: k of n
  consecutive frames farther than the critical distance show it fairly visible (`fair_mask`). A target hidden
  behind a wall until it is too late, or one that peeks out for a single frame, is untestable, not a detector's
  failure;
- late when it is testable and the target was not confirmed before the distance fell to the critical distance
  (confirmed inside it, or never).

`lateness` grades it for a search: the share of the fairly visible approach (from the first fair frame's
distance down to the critical distance) that went by before confirmation, capped at 1; late is lateness 1.
Time-to-collision at confirmation is range over closing speed (the frames' distance against their time), NaN
when the two are not closing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from garage_exp.core.config_nodes import register_node
from garage_exp.core.errors import GarageError


def speed_ms(ego) -> float:
    return float(ego.speed) / 3.6


def stopping_distance(ego) -> float:
    """Metres from the confirming frame to standstill: reaction then constant deceleration."""
    v = speed_ms(ego)
    return v * float(ego.reaction) + v * v / (2.0 * float(ego.deceleration))


def critical_distance(ego) -> float:
    """Camera-to-target distance under which a confirmation comes too late to stop short of the target."""
    return stopping_distance(ego) + float(ego.margin)


@dataclass
class EgoConf:
    """The `ego` node's schema, beside its check (check_ego), registered below it: how the ego
    drives and when it must know. Its stopping distance is speed x reaction + speed^2 / (2 deceleration); a
    target first confirmed (k hits in n frames) nearer than that plus `margin` (camera to the target's centre)
    was seen too late to stop. Sources in docs/late.md."""

    speed: float = 10.0  # km/h, an AVP car's manoeuvring speed
    reaction: float = 0.5  # s, from the confirming frame to full braking (system latency and brake build-up)
    deceleration: float = 3.4  # m/s^2, AASHTO's braking rate for stopping sight distance
    margin: float = 2.5  # m, roof camera to front bumper (~1.5 m) and the target's half depth, stopping short
    k: int = 2  # a target is confirmed at the frame completing k hits ...
    n: int = 3  # ... within the last n frames


register_node("ego", EgoConf)


def check_ego(ego, moving: bool = True) -> None:
    """The `ego` node's values: one line naming the key on the first bad one."""
    for key in ("speed", "reaction", "margin"):
        if float(ego[key]) < 0:
            raise GarageError(f"{ego[key]} is negative", f"ego.{key}")
    if not float(ego.deceleration) > 0:
        raise GarageError(f"{ego.deceleration}: a deceleration is positive (m/s^2)", "ego.deceleration")
    if int(ego.n) < 1 or int(ego.k) < 1:
        raise GarageError(f"k={ego.k} of n={ego.n}: both are at least 1", "ego.k")
    if int(ego.k) > int(ego.n):
        raise GarageError(f"k={ego.k} hits cannot fit in n={ego.n} frames (k <= n)", "ego.k")
    if moving and not float(ego.speed) > 0:
        raise GarageError("the case moves the ego: it needs a speed above 0 km/h", "ego.speed")


def confirmed_at(hits: Sequence[bool], k: int, n: int) -> int | None:
    """The first frame index at which k of the last n frames (this one included) were hits; None if never."""
    window: list[bool] = []
    count = 0
    for i, hit in enumerate(hits):
        window.append(bool(hit))
        count += bool(hit)
        if len(window) > n:
            count -= window.pop(0)
        if count >= k:
            return i
    return None


def time_to_collision(distance: np.ndarray, time: np.ndarray, i: int) -> float:
    """Range over closing speed at frame i (the closing speed from frame i and its neighbour: the one before,
    or after for the first frame); NaN when they are not closing or time does not advance."""
    if len(distance) < 2:
        return math.nan
    a, b = (i - 1, i) if i > 0 else (0, 1)
    dt = float(time[b] - time[a])
    closing = (float(distance[a]) - float(distance[b])) / dt if dt > 0 else math.nan
    return float(distance[i]) / closing if closing > 0 else math.nan


@dataclass
class Trajectory:
    """One trajectory's verdict; distances in metres (camera to the target's centre), times in seconds."""

    testable: bool
    late: bool
    lateness: float  # NaN when not testable
    detection_distance: float  # NaN when never confirmed
    ttc: float  # at confirmation; NaN when never confirmed or not closing
    first_fair_distance: float  # the farthest fair frame's distance before the critical one; NaN if none
    confirmed_frame: float  # the frame index within the trajectory; NaN when never


def judge(distance: Sequence[float], time: Sequence[float], hit: Sequence[bool], fair: Sequence[bool],
          ego) -> Trajectory:
    """The verdict on one trajectory's frames, in the order they were driven."""
    d = np.asarray(distance, dtype=float)
    t = np.asarray(time, dtype=float)
    critical = critical_distance(ego)
    before = np.asarray(fair, dtype=bool) & (d > critical)
    first_fair = float(d[before][0]) if before.any() else math.nan
    i = confirmed_at(list(hit), int(ego.k), int(ego.n))
    det = float(d[i]) if i is not None else math.nan
    ttc = time_to_collision(d, t, i) if i is not None else math.nan
    in_time = i is not None and det > critical
    # untestable: not confirmed in time, and not even a perfect detector could have been
    if not in_time and confirmed_at(list(before), int(ego.k), int(ego.n)) is None:
        return Trajectory(False, False, math.nan, det, ttc, first_fair, math.nan if i is None else float(i))
    # A confirmation farther than the first fair frame (a partly hidden target found early) counts as in time.
    if i is None or det <= critical:
        lateness = 1.0
    elif not before.any() or first_fair <= critical + 1e-9:  # confirmed in time, before any fair frame
        lateness = 0.0
    else:
        lateness = float(np.clip((first_fair - det) / (first_fair - critical), 0.0, 1.0))
    late = i is None or det <= critical
    return Trajectory(True, bool(late), lateness, det, ttc, first_fair, math.nan if i is None else float(i))


TRAJECTORY_KEYS = ("label", "replicate")


def trajectories(table: pd.DataFrame, times: dict[int, float], fair: pd.Series, ego,
                 threshold: float) -> pd.DataFrame:
    """One row per trajectory (label and replicate) of one camera's frames: its verdict. `times`: each shot's
    time (s), `fair`: the frames' fair mask (aligned with `table`)."""
    t = table.assign(time=table.shot.map(times).astype(float), fair=fair.astype(bool),
                     hit=table.composite >= threshold)
    keys = [k for k in TRAJECTORY_KEYS if k in t]
    rows = []
    for key, g in t.groupby(keys, sort=False):
        g = g.sort_values("time", kind="stable")
        verdict = judge(g.distance.to_numpy(), g.time.to_numpy(), g.hit.to_numpy(), g.fair.to_numpy(), ego)
        key = key if isinstance(key, tuple) else (key,)
        rows.append({**dict(zip(keys, key)), **asdict(verdict)})
    return pd.DataFrame(rows)


# The job's late metrics (`summary`'s keys, logged with its run), and those that tables show, in words (the sweep
# report's per-run table, a search report's trials).
METRICS = ("late", "lateness", "late_trajectories", "late_testable", "detection_distance", "ttc_at_detection",
           "stopping_distance", "critical_distance")
LABELS = {"late": "late (share)", "late_testable": "testable trajectories",
          "detection_distance": "detection distance (m)", "ttc_at_detection": "TTC at detection (s)",
          "critical_distance": "critical distance (m)"}


def summary(per: pd.DataFrame, ego) -> dict[str, float]:
    """The job's late metrics over its trajectories: `late` is the share of testable trajectories that were
    late (NaN when none is testable), `lateness` their mean grade, detection distance and TTC over the
    confirmed ones."""
    testable = per[per.testable] if len(per) else per
    confirmed = per[per.detection_distance.notna()] if len(per) else per

    def mean(series) -> float:
        return float(series.mean()) if len(series) and series.notna().any() else math.nan

    return {"late": mean(testable.late.astype(float)) if len(testable) else math.nan,
            "lateness": mean(testable.lateness) if len(testable) else math.nan,
            "late_trajectories": float(testable.late.sum()) if len(testable) else 0.0,
            "late_testable": float(len(testable)),
            "detection_distance": mean(confirmed.detection_distance) if len(confirmed) else math.nan,
            "ttc_at_detection": mean(confirmed.ttc) if len(confirmed) else math.nan,
            "stopping_distance": stopping_distance(ego), "critical_distance": critical_distance(ego)}


def confirmed_text(distance: float | None, digits: int = 1) -> str:
    """Where the target was confirmed, in words: "confirmed at 7.2 m", or "never confirmed" (None or NaN)."""
    if distance is None or math.isnan(distance):
        return "never confirmed"
    return f"confirmed at {distance:.{digits}f} m"


def line(metrics: dict) -> str:
    """The late verdict in one line, for stdout."""
    n = int(metrics["late_testable"])
    head = (f"late: {int(metrics['late_trajectories'])} of {n} testable trajectories seen too late to stop "
            f"(critical distance {metrics['critical_distance']:.1f} m")
    if n == 0:
        return head + "; the target was never fairly visible before it: untestable)"
    if math.isnan(metrics["detection_distance"]):
        return head + "; never confirmed)"
    return (head + f"; confirmed at {metrics['detection_distance']:.1f} m on average, time-to-collision "
            f"{metrics['ttc_at_detection']:.1f} s)")
