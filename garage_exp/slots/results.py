"""Slot detection scored as PS2.0 scores it (Zhang et al., 2018; the DMPR-PS evaluation, Huang et al., 2019).

- A found marking point matches a truth point when it lies within `point_tolerance_m` of it and its direction
  within `angle_tolerance_deg` (PS2.0: 10 px of a 600 px = 10 m image, 0.167 m, and 30 degrees). The point's
  shape (T or L) is not compared. Each point matches at most once: candidate pairs are taken by the found point's
  score, then by distance.
- A found slot matches a truth slot when both its entrance points lie within `point_tolerance_m` of the truth
  slot's two entrance points (in either order) and it opens to the same side of the entrance line.
- Free/occupied accuracy: over matched slots where both the truth and the detector decide.
- Fairness: truth slots marked unfair (`fair[k]` False: corners not seen) are not counted as misses, and a found
  slot matched to one is not a false positive; a truth point is unfair when every truth slot it opens is
  unfair, or when it lies outside the image. Found points and slots below `min_score` are dropped first.
- Counts (tp, fp, fn, ...) are kept so frames pool (`pool`); a rate whose denominator is 0 is NaN.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from garage_exp.slots.marks import SlotFrame

COUNTS = ("point_tp", "point_fp", "point_fn", "slot_tp", "slot_fp", "slot_fn", "occupancy_right", "occupancy_n",
          "point_error_sum_m", "point_angle_sum_deg")


def _angle_deg(a: float, b: float) -> float:
    d = (a - b) % (2 * math.pi)
    return math.degrees(min(d, 2 * math.pi - d))


def _greedy(pairs: list[tuple[float, float, int, int]]) -> dict[int, int]:
    """found -> truth, one-to-one, taking the candidates by score (highest first), then distance."""
    taken_f, taken_t, out = set(), set(), {}
    for _, _, f, t in sorted(pairs):
        if f not in taken_f and t not in taken_t:
            taken_f.add(f)
            taken_t.add(t)
            out[f] = t
    return out


def _rate(num: float, den: float) -> float:
    return num / den if den else float("nan")


def rates(counts: dict[str, float]) -> dict[str, float]:
    """Counts with the rates they give."""
    c = dict(counts)
    c["point_precision"] = _rate(c["point_tp"], c["point_tp"] + c["point_fp"])
    c["point_recall"] = _rate(c["point_tp"], c["point_tp"] + c["point_fn"])
    c["slot_precision"] = _rate(c["slot_tp"], c["slot_tp"] + c["slot_fp"])
    c["slot_recall"] = _rate(c["slot_tp"], c["slot_tp"] + c["slot_fn"])
    c["occupancy_accuracy"] = _rate(c["occupancy_right"], c["occupancy_n"])
    c["point_error_m"] = _rate(c["point_error_sum_m"], c["point_tp"])
    c["point_angle_deg"] = _rate(c["point_angle_sum_deg"], c["point_tp"])
    return c


def score(truth: SlotFrame, found: SlotFrame, fair: list[bool] | None, conf) -> dict[str, float]:
    """One frame's PS2.0 metrics; conf: the `slot_detector.metrics` node (point_tolerance_m,
    angle_tolerance_deg, min_score). Pixel distances are read at the truth's metres per pixel."""
    tol = float(conf.point_tolerance_m) / truth.meters_per_pixel
    max_angle = float(conf.angle_tolerance_deg)
    fair = [True] * len(truth.slots) if fair is None else [bool(f) for f in fair]
    if len(fair) != len(truth.slots):
        raise ValueError(f"fair has {len(fair)} entries for {len(truth.slots)} truth slots")
    keep = [k for k, q in enumerate(found.points) if q.score >= float(conf.min_score)]
    scale = found.meters_per_pixel / truth.meters_per_pixel  # a detector may work at its own resolution
    fxy = {k: np.array([found.points[k].x, found.points[k].y]) * scale for k in keep}
    txy = [np.array([q.x, q.y]) for q in truth.points]

    width, height = truth.size
    point_fair = [0 <= q.x < width and 0 <= q.y < height for q in truth.points]
    opens: dict[int, list[bool]] = {}
    for s, f in zip(truth.slots, fair):
        opens.setdefault(s.p1, []).append(f)
        opens.setdefault(s.p2, []).append(f)
    point_fair = [inside and any(opens.get(k, [True])) for k, inside in enumerate(point_fair)]

    pairs = []
    for f in keep:
        for t, q in enumerate(truth.points):
            dist = float(np.linalg.norm(fxy[f] - txy[t]))
            if dist <= tol and _angle_deg(found.points[f].direction, q.direction) <= max_angle:
                pairs.append((-found.points[f].score, dist, f, t))
    matched = _greedy(pairs)
    c = dict.fromkeys(COUNTS, 0.0)
    for f in keep:
        t = matched.get(f)
        if t is None:
            c["point_fp"] += 1
        elif point_fair[t]:
            c["point_tp"] += 1
            c["point_error_sum_m"] += float(np.linalg.norm(fxy[f] - txy[t])) * truth.meters_per_pixel
            c["point_angle_sum_deg"] += _angle_deg(found.points[f].direction, truth.points[t].direction)
    c["point_fn"] = sum(1 for t, ok in enumerate(point_fair) if ok and t not in matched.values())

    slots = [s for s in found.slots if s.score >= float(conf.min_score)]
    spairs = []
    for f, s in enumerate(slots):
        a, b = np.array(s.corners[0]) * scale, np.array(s.corners[1]) * scale
        for t, ts in enumerate(truth.slots):
            ta, tb = np.array(ts.corners[0]), np.array(ts.corners[1])
            d = min(max(np.linalg.norm(a - ta), np.linalg.norm(b - tb)),
                    max(np.linalg.norm(a - tb), np.linalg.norm(b - ta)))  # the entrance in either order
            if d <= tol and _same_side(np.array(s.corners) * scale, np.array(ts.corners)):
                spairs.append((-s.score, float(d), f, t))
    smatched = _greedy(spairs)
    for f, s in enumerate(slots):
        t = smatched.get(f)
        if t is None:
            c["slot_fp"] += 1
        elif fair[t]:
            c["slot_tp"] += 1
            truth_occ = truth.slots[t].occupied
            if s.occupied is not None and truth_occ is not None:
                c["occupancy_n"] += 1
                c["occupancy_right"] += float(s.occupied == truth_occ)
    c["slot_fn"] = sum(1 for t, ok in enumerate(fair) if ok and t not in smatched.values())
    return rates(c)


def _same_side(found: np.ndarray, truth: np.ndarray) -> bool:
    """The two quads open to the same side of the truth's entrance line (their centres on one side of it)."""
    a, b = truth[0], truth[1]
    v = b - a

    def side(quad: np.ndarray) -> float:
        m = quad.mean(axis=0) - a
        return float(v[0] * m[1] - v[1] * m[0])

    return side(found) * side(truth) > 0


def pool(frames: Iterable[dict[str, float]]) -> dict[str, float]:
    """Many frames' metrics as one: counts summed, rates recomputed from them."""
    total = dict.fromkeys(COUNTS, 0.0)
    for frame in frames:
        for key in COUNTS:
            total[key] += float(frame[key])
    return rates(total)
