"""Where an actor stands: a placement on a site (a path, a bay, the gap between two bays, another actor) turned
into a pose, and the footprint check that keeps two actors from standing in one another."""

from __future__ import annotations

import math

import numpy as np

from garage_exp.core.errors import GarageError, Infeasible
from garage_exp.scenario.sites import Path, Site, SiteBay, compass
from garage_exp.scene.description import Pose


def site_bay(site: Site, ref, bays: dict, where: str) -> SiteBay:
    """A bay of the site by the scenario's name for it (`bays: {far: 3}`), by index, or by side and index
    (`right:3`)."""
    key = str(bays.get(str(ref), ref))
    side, _, index = key.rpartition(":")
    row = site.sides.get(side) if side else site.bays
    try:
        return row[int(index)]
    except (TypeError, ValueError, IndexError):
        sides = ", ".join(f"{k}: {len(v)}" for k, v in site.sides.items())
        raise GarageError(f"the site {site.name} has no bay {str(ref)!r} ({len(site.bays)} bays"
                          f"{'; by side ' + sides if sides else ''}; names: {', '.join(bays) or 'none'})",
                          where) from None


def site_path(site: Site, name: str, where: str) -> Path:
    try:
        return site.paths[name]
    except KeyError:
        raise GarageError(f"the site {site.name} has no path {name!r} (have {', '.join(site.paths)})",
                          where) from None


def path_position(site: Site, actor, length: float, bays: dict, where: str) -> float:
    """The actor's distance along its path (its centre), from `distance` and how it is counted; one the path
    has no room for is an error, or trimmed to the room with `clip: true`."""
    path = site_path(site, actor.path, where + ".path")
    if actor.before:  # counted back from a bay, it may stand beyond the path's start (case 3's ego)
        bay = site_bay(site, actor.before, bays, where + ".before").bay
        return path.along(bay.x, bay.y) - float(actor.distance)
    if actor.align == "start":  # the actor's rear `distance` metres past the path's start
        return fit_on_path(path, actor, path.lo + length / 2 + float(actor.distance), length, where,
                           f"{float(actor.distance):g} m from its start (align: start)", margin=0.0, rear=True)
    if actor.align != "centre":
        raise GarageError(f"unknown align {actor.align!r} (centre | start)", where + ".align")
    return fit_on_path(path, actor, float(actor.distance), length, where)


def describe_path(path: Path, name: str) -> str:
    """`'stem' (from cell (4, 7) towards S, 9.2 m long)`: a path as a message names it."""
    towards = compass(math.degrees(math.atan2(path.axis[1], path.axis[0])))
    start = f"cell {path.cell}" if path.cell is not None else f"({path.origin[0]:.1f}, {path.origin[1]:.1f})"
    return f"{name!r} (from {start} towards {towards}, {path.hi - path.lo:.1f} m long)"


def room(path: Path, length: float, margin: float | None = None) -> tuple[float, float]:
    """Where the centre of an actor `length` long may stand on the path: `margin` m (the path's MARGIN by
    default) from either end."""
    lo, hi = path.room(length)
    if margin is None:
        return lo, hi
    return path.lo + length / 2 + margin, path.hi - length / 2 - margin


def no_room(path: Path, name: str, actor: str, asked: str, length: float, where: str,
            margin: float | None = None, rear: bool = False) -> GarageError:
    """The GarageError for a distance a path has no room for: the actor (its key, `case.actors.ego`), the
    distance, the path, its length and the room it leaves (for its centre, or its rear from the path's start)."""
    lo, hi = room(path, length, margin)
    who = actor.rpartition(".")[2]
    base, part = (path.lo + length / 2, "rear") if rear else (0.0, "centre")
    fits = (f"{who}, {length:.1f} m long, fits with its {part} {lo - base:.1f} to {hi - base:.1f} m along it"
            if lo <= hi else f"too short for {who}, {length:.1f} m long")
    return GarageError(f"{asked} does not fit {who}'s path {describe_path(path, name)}: {fits}; give a distance "
                       f"that fits, or {actor}.clip=true to trim it to the path", where)


def fit_on_path(path: Path, actor, s: float, length: float, where: str, asked: str = "",
                margin: float | None = None, rear: bool = False) -> float:
    """s (the actor's centre, in the path's own frame) when the actor fits on the path; trimmed to the room the
    path leaves with `clip: true` (an opt-in: a short lane on a small plan); else GarageError naming the actor,
    the asked distance, the path and its length."""
    lo, hi = room(path, length, margin)
    if lo - 1e-9 <= s <= hi + 1e-9:
        return s
    if getattr(actor, "clip", False) and lo <= hi:
        return min(max(s, lo), hi)
    raise no_room(path, actor.path, where, asked or f"{float(actor.distance):g} m", length, where + ".distance",
                  margin, rear)


def pose_on_path(site: Site, actor, length: float, bays: dict, where: str) -> Pose:
    path = site_path(site, actor.path, where + ".path")
    s = path_position(site, actor, length, bays, where)
    if actor.before:  # counted in the world's frame along the axis (the bay's projection onto the lane)
        x, y = path.at_world(s)
        if actor.offset:
            x, y = x - actor.offset * path.axis[1], y + actor.offset * path.axis[0]
    else:
        x, y = path.point(s, float(actor.offset))
    return Pose(x, y, 0.0, (path.heading + float(actor.yaw)) % 360.0)


def pose_in_bay(site: Site, actor, length: float, bays: dict, where: str) -> Pose:
    """In a bay, nose to the lane, centred, or with the front bumper `gap` metres behind the bay line; `offset`
    metres to the left of its heading. A negative `gap` is a car pulling out: its nose that far past the bay line
    into the lane, straight out along the bay's axis, at most its whole length (its rear bumper on the line)."""
    sb = actor.bay if isinstance(actor.bay, SiteBay) else site_bay(site, actor.bay, bays, where + ".bay")
    bay, u = sb.bay, sb.facing
    inset = 0.0
    if actor.gap is not None:
        gap = float(actor.gap)
        lo, hi = pull_out_limit(length), bay.depth - length
        if not (math.isfinite(gap) and lo - 1e-9 <= gap <= hi + 1e-9):
            raise GarageError(f"gap {gap:g} m does not fit a {length:.2f} m actor in a {bay.depth:.2f} m bay: a gap "
                              f"is from {lo:.2f} m (pulled out into the lane by its whole length) to {hi:.2f} m (at "
                              "the back of the bay)", where + ".gap")
        inset = bay.depth / 2 - length / 2 - gap
    side = float(actor.offset)
    return Pose(bay.x + u[0] * inset - u[1] * side, bay.y + u[1] * inset + u[0] * side, 0.0,
                (bay.yaw + float(actor.yaw)) % 360.0)


def pull_out_limit(length: float) -> float:
    """The most negative `gap` of an actor `length` long: pulled out of its bay by its whole length."""
    return -float(length)


def pose_between(site: Site, actor, bays: dict, where: str) -> Pose:
    """In the gap between two neighbouring bays, `out` metres past the bay line into the lane, facing it, and
    `offset` metres to the left of that heading (where in the gap a person stands)."""
    if len(actor.between) != 2:
        raise GarageError(f"between names two bays, got {list(actor.between)}", where + ".between")
    a, b = (site_bay(site, ref, bays, where + ".between") for ref in actor.between)
    u = a.facing
    mx, my = (a.bay.x + b.bay.x) / 2, (a.bay.y + b.bay.y) / 2
    reach = a.bay.depth / 2 + float(actor.out)
    side = float(actor.offset)
    yaw = math.degrees(math.atan2(u[1], u[0])) % 360.0
    return Pose(mx + u[0] * reach - u[1] * side, my + u[1] * reach + u[0] * side, 0.0,
                (yaw + float(actor.yaw)) % 360.0)


def pose_relative(ref: Pose, ref_axis: tuple[float, float], actor, sizes=None) -> Pose:
    """`distance` metres ahead of another actor along its path's axis, `offset` to its left. With `gap` (and
    `sizes`: the other actor's extent and this one's), it stands before the other instead, `gap` metres of free
    floor between them along the axis (an occluder that far in front of its target, seen from the ego), facing
    along the axis turned its own `yaw` (not the other's)."""
    d, o = float(actor.distance), float(actor.offset)
    yaw = ref.yaw + float(actor.yaw)
    if actor.gap is not None and sizes is not None:  # it faces along the axis, turned `yaw`, not as the other
        heading = math.degrees(math.atan2(ref_axis[1], ref_axis[0]))
        yaw = heading + float(actor.yaw)
        d = -(float(actor.gap) + _half_along(sizes[0], ref.yaw - heading) + _half_along(sizes[1], float(actor.yaw)))
    ax, ay = ref_axis
    return Pose(ref.x + d * ax - o * ay, ref.y + d * ay + o * ax, 0.0, yaw % 360.0)


def _half_along(extent, yaw: float) -> float:
    """Half an actor's reach along an axis it is turned `yaw` degrees from (its footprint's projection)."""
    c, s = abs(math.cos(math.radians(yaw))), abs(math.sin(math.radians(yaw)))
    return (c * extent[0] + s * extent[1]) / 2


def footprint(pose: Pose, extent: tuple[float, float, float]) -> np.ndarray:
    """The four corners (x, y) of an actor's footprint."""
    c, s = math.cos(math.radians(pose.yaw)), math.sin(math.radians(pose.yaw))
    hl, hw = extent[0] / 2, extent[1] / 2
    local = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])
    return local @ np.array([[c, s], [-s, c]]) + np.array([pose.x, pose.y])


def hull(points: np.ndarray) -> np.ndarray:
    """The convex hull of points (x, y), counter-clockwise: the ground an actor sweeps moving straight from one
    footprint to another (the hull of the two)."""
    pts = sorted({(round(float(x), 9), round(float(y), 9)) for x, y in points})
    if len(pts) < 3:
        return np.array(pts, dtype=float)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    upper: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1], dtype=float)


TOLERANCE = 0.02  # metres two footprints may share: a box is a body's or a car's outline, not its shape


def overlap(a: np.ndarray, b: np.ndarray, tolerance: float = TOLERANCE) -> bool:
    """Two convex footprints overlap by more than `tolerance` metres (separating-axis test)."""
    for poly in (a, b):
        for k in range(len(poly)):
            edge = poly[(k + 1) % len(poly)] - poly[k]
            normal = np.array([-edge[1], edge[0]]) / (np.hypot(*edge) or 1.0)
            pa, pb = a @ normal, b @ normal
            if min(pa.max(), pb.max()) - max(pa.min(), pb.min()) <= tolerance:
                return False
    return True


def clash(poses: dict[str, Pose | None], made: dict, only: set | None = None) -> tuple[str, str] | None:
    """The first two actors standing in one another (footprints overlapping by more than TOLERANCE), or None.
    This is the rule of what placements are legal: a job holds every frame to it (check_overlaps), and the
    adversary's action space every value it can reach (`sweep_clash`, garage_exp/gym/limits.py).
    `only`: pairs with one of these."""
    return sweep_clash([poses], made, only)


def sweep_clash(corners: list[dict[str, Pose | None]], made: dict, only: set | None = None
                ) -> tuple[str, str] | None:
    """`clash` for every placement in a box of placement values at once: `corners` are the poses at the box's
    corners (one frame each). A placement moves an actor straight with each value (a path's distance and
    offset, a bay's gap, a gap's out and offset), so two actors' relative position over the box is the convex
    hull of their relative positions at its corners: for each pair, the hull of one's footprints seen from the
    other is tested against the other's. An actor whose heading changes over the box (a moved yaw) is tested
    at each corner alone (give such corners densely). One corner is `clash` itself."""
    ref = corners[0]
    names = [n for n, p in ref.items() if p is not None]
    feet = [{n: footprint(c[n], made[n].extent) for n in names} for c in corners]
    for k, a in enumerate(names):
        for b in names[k + 1:]:
            if only is not None and a not in only and b not in only:
                continue
            turned = any(c[n].yaw != ref[n].yaw for c in corners for n in (a, b))
            if turned:
                hit = any(overlap(f[a], f[b]) for f in feet)
            else:  # a's footprint at each corner, shifted by how far b moved from the first corner
                seen = [f[a] - np.array([c[b].x - ref[b].x, c[b].y - ref[b].y]) for f, c in zip(feet, corners)]
                swept = hull(np.vstack(seen)) if len(seen) > 1 else seen[0]
                hit = overlap(swept, feet[0][b])
            if hit:
                return a, b
    return None


def farthest(fits, start: float, bound: float, step: float = 1e-4) -> float | None:
    """How far from `start` towards `bound` a value may go: the farthest v (to `step`, rounded towards start)
    with fits(v), where fits(v) says whether the whole range start..v is legal (so it fails only further out,
    and halving finds the edge); `bound` itself when it fits; None when not even `start` does."""
    if fits(bound):
        return float(bound)
    if not fits(start):
        return None
    good, bad = float(start), float(bound)
    while abs(bad - good) > step / 4:
        mid = (good + bad) / 2
        good, bad = (mid, bad) if fits(mid) else (good, mid)
    steps = (good - start) / step
    return round(start + math.copysign(math.floor(abs(steps) + 1e-9), steps) * step, 6)


def check_overlaps(poses: dict[str, Pose], made: dict, label: str, value: float, only: set | None = None,
                   where: str = "case.actors", room=None) -> None:
    """No two actors stand in one another (`only`: pairs with one of these); else Infeasible naming them, with
    `room(pair)`'s word on how far the placement may go (build.py: a person's offset in its gap)."""
    pair = clash(poses, made, only)
    if pair is not None:
        a, b = pair
        hint = room(pair) if room is not None else ""
        # a one-shot scenario's one frame has no position along a motion (nan): only its variant is named
        at = f", position {value:g}" if value == value else ""
        raise Infeasible(f"actors {a} and {b} overlap (variant {label!r}{at}){hint}", where, pair)
