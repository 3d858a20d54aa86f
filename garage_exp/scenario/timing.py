"""When an along-moving actor (a person stepping out as the ego drives) is where: its walk from standstill, and
its start timed by the ego's travel (`at`) or synchronised to arrive as the ego does (`meet`).

A walk covers `accelerate` metres at a constant acceleration up to `speed`, then keeps that speed (Euro NCAP's
pedestrian targets reach their speed after 1 m); `accelerate: 0` is at speed from the first step.
"""

from __future__ import annotations

import math


def travelled(along, tau: float) -> float:
    """Metres covered `tau` seconds after the start (0 before it)."""
    v, a = float(along.speed), float(along.accelerate or 0.0)
    if tau <= 0 or v <= 0:
        return 0.0
    if a <= 0:
        return v * tau
    ramp = 2.0 * a / v  # seconds to reach v over a metres
    if tau <= ramp:
        return v * tau * tau / (2.0 * ramp)
    return a + v * (tau - ramp)


def speed_at(along, tau: float) -> float:
    """The actor's speed (m/s) `tau` seconds after its start (travelled's derivative)."""
    v, a = float(along.speed), float(along.accelerate or 0.0)
    if tau <= 0 or v <= 0:
        return 0.0
    ramp = 2.0 * a / v if a > 0 else 0.0
    return v * tau / ramp if tau < ramp else v


def travel_time(along, metres: float) -> float:
    """Seconds from the start to cover `metres` (inf when the actor does not move)."""
    v, a = float(along.speed), float(along.accelerate or 0.0)
    if metres <= 0:
        return 0.0
    if v <= 0:
        return math.inf
    if a <= 0:
        return metres / v
    ramp = 2.0 * a / v
    if metres <= a:
        return ramp * math.sqrt(metres / a)
    return ramp + (metres - a) / v


def start_time(along, time_at) -> float:
    """Seconds after the first frame when the actor sets off: at the ego's `at`, or so as to reach `end` at the
    ego's `meet` (negative: it was already on its way at the first frame). `time_at(value)`: the ego's time at a
    motion value."""
    if along.meet is not None:
        metres = path_length(along) if along.path else abs(float(along.end) - float(along.start))
        return time_at(float(along.meet)) - travel_time(along, metres)
    return time_at(float(along.at)) if along.at is not None else 0.0


def path_length(along) -> float:
    """Metres along a co-motion's `path` of [distance, offset] points."""
    points = [(float(d), float(o)) for d, o in along.path]
    return sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(points, points[1:]))
