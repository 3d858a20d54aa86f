"""What the adversary may do: each moved value's bounds, top speed and top acceleration, checked against what
the actor could physically do. The limits are the action space's bounds, so no action can make a child run at
20 km/h: an action is a velocity in [-1, 1] x the top speed, reached no faster than the top acceleration.

Top speeds of people (m/s) are running speeds: a young child about 3 m/s, an adult about 3.5 m/s in a
garage's few metres (sprinters' 10 m/s needs a run-up no gap between parked cars gives). The accelerations are a
running start's. A vehicle's row is a car pulling out of its bay (`gap`, garage_exp/PullOut-v0): at most 2 m/s
(7 km/h, a brisk walk: a driver leaving a bay in a garage creeps), reached no faster than 2 m/s^2 (a moderate
start from standstill, not a launch); a car drives no further out than its whole length
(scenario/place.py's pull-out limit, checked with the mover's bounds when the environment is made).

Where an actor may stand is not the adversary's to decide: the job's rule (scenario/place.py `clash`: no two
actors' footprints in one another) holds every value the action space can reach, in every frame of the drive
(`fit_bounds`), so that each episode reruns as a job. A bound left open (null) is as far as the actor fits: a
child's offset in its gap runs to the parked cars' sides, the gap's width less the child's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from garage_exp.core.errors import GarageError, check_range
from garage_exp.scenario.place import farthest

TOP_SPEED = {"child": 3.0, "adult": 3.5, "vehicle": 2.0}  # m/s (vehicle: pulling out of a bay)
TOP_ACCEL = {"child": 3.0, "adult": 3.0, "vehicle": 2.0}  # m/s^2
METRES = ("distance", "offset", "out", "gap")  # keys in metres: their speed is the actor's own
DEGREES_PER_S = 180.0  # `yaw`: a person turning round in a second
REACH = 3.0  # m: how far from its start an open bound (null) is looked for (a gap's width, half a lane)
FIT_STEP = 1e-3  # m: an open bound is found to a millimetre, rounded towards the start


@dataclass(frozen=True)
class Mover:
    """One moved value with its limits resolved (what the env steps)."""

    actor: str
    key: str
    low: float
    high: float
    start: float
    rate: float  # top |velocity| of the value (m/s, or degrees/s for yaw)
    accel: float  # top |change of velocity| per second
    once: bool
    open: tuple[str, ...] = ()  # the bounds left open (null): `fit_bounds` finds them

    @property
    def name(self) -> str:
        return f"{self.actor}.{self.key}"


def physical(actor) -> str:
    """The row of TOP_SPEED an actor's body falls in."""
    if actor.kind == "person":
        return "child" if actor.age == "child" else "adult"
    if actor.kind == "vehicle":
        return "vehicle"
    return ""


def resolve_movers(movers, actors: dict, movable: tuple[str, ...]) -> list[Mover]:
    """The config's movers checked against the episode's actors (name -> ActorConf) and the physical limits;
    GarageError naming `gym.movers.K.<key>` on the first bad one."""
    if not movers:
        raise GarageError("the adversary moves nothing: give at least one mover", "gym.movers")
    out: list[Mover] = []
    seen = set()
    for k, m in enumerate(movers):
        where = f"gym.movers.{k}"
        if m.actor not in actors or m.actor == "ego":
            have = ", ".join(n for n in actors if n != "ego")
            raise GarageError(f"no actor {m.actor!r} to move (the ego drives by the case's motion; have {have})",
                              where + ".actor")
        if m.key not in movable:
            raise GarageError(f"{m.key!r} is not a placement value ({' | '.join(movable)})", where + ".key")
        if (m.actor, m.key) in seen:
            raise GarageError(f"{m.actor}.{m.key} is moved twice", where)
        seen.add((m.actor, m.key))
        stepped = [n.key for n in out if n.actor == m.actor and not n.once]
        if stepped and not m.once:  # a scenario moves an actor along by one key (case.motion.along.<actor>)
            raise GarageError(f"{m.actor} already moves its {stepped[0]} each step: an exported episode moves an "
                              f"actor by one key; give {m.key} once: true", where + ".once")
        body = physical(actors[m.actor])
        if not body:
            raise GarageError(f"{m.actor} is a {actors[m.actor].kind}: it cannot move by itself", where + ".actor")
        metres = m.key in METRES
        top = TOP_SPEED[body] if metres else DEGREES_PER_S
        top_accel = TOP_ACCEL[body] if metres else 4 * DEGREES_PER_S
        rate = top if m.rate is None else float(m.rate)
        accel = top_accel if m.accel is None else float(m.accel)
        unit = "m/s" if metres else "degrees/s"
        if not 0 < rate <= top:
            raise GarageError(f"{rate:g} {unit} is outside 0-{top:g} {unit}, what a{'n' if body[0] in 'a' else ''} "
                              f"{body} can do", where + ".rate")
        check_range(accel, 1e-6, top_accel, where + ".accel", f"{accel:g} {unit}/s")
        start = float(getattr(actors[m.actor], m.key)) if m.start is None else float(m.start)
        open_ = tuple(side for side in ("low", "high") if getattr(m, side) is None)
        if open_ and not metres:
            raise GarageError(f"a {m.key} mover needs both bounds (an open bound is looked for in metres)",
                              f"{where}.{open_[0]}")
        low = start - REACH if m.low is None else float(m.low)
        high = start + REACH if m.high is None else float(m.high)
        if not low < high:
            raise GarageError(f"low {m.low} is not below high {m.high}", where + ".low")
        if not low <= start <= high:
            raise GarageError(f"{m.actor}'s {m.key} starts at {start:g}, outside {low:g}..{high:g}",
                              where + ".start")
        out.append(Mover(m.actor, m.key, low, high, start, rate, accel, bool(m.once), open_))
    return out


def fit_bounds(movers: list[Mover], clash_in) -> list[Mover]:
    """The movers' bounds held to where the actors may stand. `clash_in(box)` (box: mover name -> (lo, hi))
    says which two actors some values in the box put in one another in some frame of the drive (the job's rule,
    scenario/place.py), or ''. All values at their starts first; then each mover in turn widens to its bounds:
    a bound given that clashes is refused, naming it and how far the mover fits; an open one (null) goes as far
    as it fits. GarageError naming `gym.movers.K.<bound>`."""
    box = {m.name: (m.start, m.start) for m in movers}
    hit = clash_in(box)
    if hit:
        raise GarageError(f"the movers' starts put {hit}", "gym.movers")
    out = []
    for k, m in enumerate(movers):
        for side in ("low", "high"):
            bound = getattr(m, side)

            def widened(v: float, side=side, name=m.name) -> dict:
                lo, hi = box[name]
                return {**box, name: (v, hi) if side == "low" else (lo, v)}

            fits = farthest(lambda v: not clash_in(widened(v)), m.start, bound, FIT_STEP)
            if fits != bound and side not in m.open:
                raise GarageError(f"{m.name} at {bound:g} puts {clash_in(widened(bound))}: it fits to {fits:g} (give "
                                  f"{side}: {fits:g}, or null: as far as it fits)", f"gym.movers.{k}.{side}")
            box[m.name] = widened(fits)[m.name]
        lo, hi = box[m.name]
        if not lo < hi:
            raise GarageError(f"{m.name} has no room to move either way from its start {m.start:g}", f"gym.movers.{k}")
        out.append(replace(m, low=lo, high=hi, open=()))
    return out


def advance(mover: Mover, value: float, velocity: float, action: float, dt: float) -> tuple[float, float]:
    """One step of one moved value: the action asks for a velocity (share of the top speed); the velocity
    follows it no faster than the top acceleration; the value stays within its bounds (and stops there)."""
    wanted = float(max(-1.0, min(1.0, action))) * mover.rate
    step = mover.accel * dt
    velocity = velocity + max(-step, min(step, wanted - velocity))
    moved = value + velocity * dt
    if moved <= mover.low or moved >= mover.high:
        moved, velocity = min(max(moved, mover.low), mover.high), 0.0
    return moved, velocity


def placed_once(mover: Mover, action: float) -> float:
    """A `once` value: the first action (-1..1) maps onto low..high."""
    a = float(max(-1.0, min(1.0, action)))
    return mover.low + (a + 1.0) / 2.0 * (mover.high - mover.low)


def summary(movers: list[Mover], values: dict[str, list[float]], dt: float, drive: list[float]) -> dict[str, float]:
    """An episode's moves as a few numbers per value (for tables and for clustering failures): a `once` value
    itself; for the others when it began to move (s, NaN: never), where the ego then was (its motion value; the
    co-motion's `at`: the drive's last value when it never moved), its mean speed while moving, its last value.
    `drive`: the ego's motion value at the start and at each frame."""
    out: dict[str, float] = {}
    for m in movers:
        seq = values.get(m.name) or []
        if m.once:
            out[m.name] = float(seq[0]) if seq else m.start
            continue
        prev = [m.start, *seq]
        steps = [abs(b - a) for a, b in zip(prev, prev[1:])]
        moving = [i for i, s in enumerate(steps) if s > 1e-6]
        out[f"{m.name}.start_s"] = float(moving[0] * dt) if moving else float("nan")
        out[f"{m.name}.at"] = float(drive[moving[0]]) if moving else float(drive[len(seq)])
        out[f"{m.name}.speed"] = float(sum(steps[i] for i in moving) / (len(moving) * dt)) if moving else 0.0
        out[f"{m.name}.end"] = float(seq[-1]) if seq else m.start
    return out
