"""Slot ground truth from the plan: every bay's corners, marking points and occupancy, in the bird's-eye view.

Plain data and geometry, no renderer. The bay lines are the ones `scene/markings.py` paints: one white line
between neighbouring bays of a cell (perpendicular to the lane edge), the cell's edge lines moved inwards by half
a line width; a bay's four corners are where its two bounding lines meet the lane edge (the entrance) and the
back of the cell. A marking point is a line's lane-side end (PS2.0's vocabulary: the garage paints no entrance
line, so the point is where a separating line meets the entrance): "T" where the line separates two bays, "L"
at the end of a row. Its direction points along the line into the slot.

Per corner, what a camera could see of it in the BEV (`Visibility`):
- "outside": off the BEV, or under the ego's body where no camera sees the floor;
- "hidden": the ray from the BEV's camera for that pixel to the corner meets a parked car, a person, a box
  or a pillar first (their boxes: a car's footprint times its height, a pillar's section to the ceiling);
- "worn": the line's paint there is gone (the `wear` factor removes a deterministic share of the pieces,
  `scene/markings.unit_hash`) or has less than `WORN` of its contrast left: the factor fades the rest to
  1 - wear, and the real look's paint texture (`materials`, scene/textures._paint) wears patches through to the
  floor, on average the share `texture_left` says;
- "visible" otherwise.
A slot is fair when a detector could have seen where it is: its entrance corners (its marking points, what
PS2.0's slots are made of) are neither outside nor hidden, and its back corners lie in the view (they may be
hidden: the plan puts a pillar at the back corners of most bays, and an occupied bay's car covers its back).
Worn paint is what makes a slot hard, not unfair.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from garage_exp.core.state import STATE
from garage_exp.slots.marks import MarkingPoint, Slot, SlotFrame
from garage_exp.render.bev import BevMaps, BevSpec
from garage_exp.scene.bays import BAY_TYPES, Bay, bays, layout
from garage_exp.scene.camera import camera_to_world, to_camera
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import Box, CameraSpec, Pose, Scene
from garage_exp.scene.markings import _drawn_by_neighbour, unit_hash

WORN = 0.25  # paint with less than this share of its fresh contrast left counts as worn away
VISIBILITY = ("visible", "worn", "hidden", "outside")  # a corner's, best first


@dataclass(frozen=True)
class Line:
    """One painted separating line's two ends in the world: `entrance` on the lane edge, `back`."""

    entrance: tuple[float, float]
    back: tuple[float, float]
    paint: float  # the paint's remaining contrast: 0 (gone) .. 1 (fresh)


@dataclass(frozen=True)
class WorldBay:
    """A bay's corners in the world: entrance p1, entrance p2, back of p2, back of p1; p1 -> p2 runs along the
    entrance so that the bay lies on its right as drawn in the BEV (image rows grow downwards)."""

    bay: str  # bay_<i>_<j>_<k>
    corners: tuple[tuple[float, float], ...]
    into: float  # world yaw (degrees) from the entrance into the bay
    shapes: tuple[str, str]  # "T" | "L" at p1 and p2
    paint: tuple[float, float, float, float]  # the paint's contrast at each corner


@dataclass(frozen=True)
class Obstacle:
    """Something standing on the floor that hides it: a box `half` (length, width) about `pose`, `height` tall."""

    name: str
    kind: str  # vehicle | person | box | pillar
    pose: Pose
    half: tuple[float, float]
    height: float

    def blocks(self, start: np.ndarray, end: np.ndarray) -> bool:
        """Whether the segment start -> end (world, 3D) passes through the box (slab test in its frame)."""
        c, s = math.cos(math.radians(self.pose.yaw)), math.sin(math.radians(self.pose.yaw))

        def local(p):
            dx, dy = p[0] - self.pose.x, p[1] - self.pose.y
            return np.array([c * dx + s * dy, -s * dx + c * dy, p[2]])

        a, b = local(start), local(end)
        lo = np.array([-self.half[0], -self.half[1], 0.0])
        hi = np.array([self.half[0], self.half[1], self.height])
        d = b - a
        t0, t1 = 0.0, 1.0
        for k in range(3):
            if abs(d[k]) < 1e-12:
                if a[k] < lo[k] or a[k] > hi[k]:
                    return False
                continue
            ta, tb = (lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]
            t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
            if t0 > t1:
                return False
        return t1 > 1e-6 and t0 < 1.0 - 1e-6


@dataclass
class SlotTruth:
    """One BEV frame's ground truth: the SlotFrame, and per slot its corners' visibility, fairness and where
    each camera images each corner ((u, v) pixels, None where the camera does not see it)."""

    frame: SlotFrame
    visibility: list[tuple[str, str, str, str]] = field(default_factory=list)
    in_cameras: list[dict[str, list[tuple[float, float] | None]]] = field(default_factory=list)

    @property
    def fair(self) -> list[bool]:
        return [vis[0] not in ("hidden", "outside") and vis[1] not in ("hidden", "outside")
                and "outside" not in vis[2:] for vis in self.visibility]

    def to_dict(self) -> dict:
        f = self.frame
        return {"meters_per_pixel": f.meters_per_pixel, "size": list(f.size),
                "points": [[p.x, p.y, p.direction, p.shape] for p in f.points],
                "slots": [{"bay": s.bay, "p1": s.p1, "p2": s.p2, "corners": [list(c) for c in s.corners],
                           "occupied": s.occupied, "visibility": list(vis), "fair": fair, "cameras": cams}
                          for s, vis, fair, cams in zip(f.slots, self.visibility, self.fair, self.in_cameras)]}


def paint_left(cell_i: int, cell_j: int, piece: int, wear: float) -> float:
    """What the `wear` factor leaves of a bay line (scene/markings.build_markings): nothing when the piece was
    removed, else the faded paint's share of its contrast with the floor."""
    if wear >= 1.0 or unit_hash(cell_i, cell_j, piece) < wear / 2:
        return 0.0
    return 1.0 - wear


@STATE.memo("process", maxsize=32)
def texture_left(paint_wear: float) -> float:
    """The mean share of a line's paint the real look's texture leaves at this wear (its patches of worn-through
    paint, scene/textures._paint, averaged over a tile of its noise): 1.00 fresh, 0.96 at 0.3, 0.50 at 0.79."""
    from garage_exp.scene.textures import fbm

    if paint_wear <= 0.0:
        return 1.0
    noise = fbm(128, np.random.default_rng(0), octaves=5, base=8)
    return float((1.0 - np.clip((noise + 1.2 * paint_wear - 0.85) * 5.0, 0.0, 1.0)).mean())


def world_bays(classified, garage, wear: float = 0.0, texture_wear: float = 0.0) -> list[WorldBay]:
    """Every bay of the plan (scene/bays.bays) with its corners on the painted lines. `wear`: the `wear` factor's;
    `texture_wear`: the paint texture's (the `materials` dress's paint wear; 0 without materials)."""
    width = float(garage.marking_width)
    texture = texture_left(round(float(texture_wear), 4))
    h = width / 2
    present = {(b.i, b.j, b.index) for b in bays(classified, garage)}
    out = []
    for bay in bays(classified, garage):
        cell = classified.cell(bay.i, bay.j)
        lay = layout(classified, cell, float(garage.bay_width))
        lines = lay.lines()
        last = len(lines) - 1
        shared = _drawn_by_neighbour(classified, lay)

        def line_at(m: int) -> tuple[float, float]:
            """The painted line m's lateral position and its paint."""
            if m == last and shared:  # the neighbour's first line: moved into the neighbour
                ni, nj = (bay.i, bay.j + 1) if lay.along_x else (bay.i - 1, bay.j)
                return lines[m] + h, paint_left(ni, nj, 0, wear) * texture
            p = lines[m] + h if m == 0 else lines[m] - h if m == last else lines[m]
            return p, paint_left(bay.i, bay.j, m, wear) * texture

        def neighbour_bay(m: int) -> bool:
            """Whether a bay lies on the far side of line m (a T) or the row ends there (an L)."""
            k = bay.index - 1 if m == bay.index else bay.index + 1
            if 0 <= k < lay.count:
                return (bay.i, bay.j, k) in present
            ni, nj = ((bay.i, bay.j + 1) if lay.along_x else (bay.i - 1, bay.j)) if k >= lay.count else (
                (bay.i, bay.j - 1) if lay.along_x else (bay.i + 1, bay.j))
            if not classified.plan.inside(ni, nj):
                return False
            other = classified.cell(ni, nj)
            if other.kind != "parking" or other.type not in BAY_TYPES or other.rotation != cell.rotation:
                return False
            return any((b[0], b[1]) == (ni, nj) for b in present)

        a0, a1 = lay.across
        entrance, back = (a1, a0) if lay.side in ("N", "E") else (a0, a1)
        (lo, paint_lo), (hi, paint_hi) = line_at(bay.index), line_at(bay.index + 1)

        def point(lateral: float, across: float) -> tuple[float, float]:
            return (lateral, across) if lay.along_x else (across, lateral)

        into = (bay.yaw + 180.0) % 360.0
        ends = [(lo, paint_lo, neighbour_bay(bay.index)), (hi, paint_hi, neighbour_bay(bay.index + 1))]
        # The bay on the right of p1 -> p2 as the BEV draws it: on the right of the entrance walked in the
        # world (seen from above, x right, y up), which the BEV's flip of rows keeps.
        ux, uy = math.cos(math.radians(into)), math.sin(math.radians(into))
        e0, e1 = point(ends[0][0], entrance), point(ends[1][0], entrance)
        if (e1[0] - e0[0]) * uy - (e1[1] - e0[1]) * ux > 0:  # into is on p1 -> p2's left
            ends.reverse()
        (l1, paint1, t1), (l2, paint2, t2) = ends
        corners = (point(l1, entrance), point(l2, entrance), point(l2, back), point(l1, back))
        out.append(WorldBay(bay_id(bay), corners, into, ("T" if t1 else "L", "T" if t2 else "L"),
                            (paint1, paint2, paint2, paint1)))
    return out


def bay_id(bay: Bay) -> str:
    return f"bay_{bay.i}_{bay.j}_{bay.index}"


def obstacles(scene: Scene, poses: dict[str, Pose | None] | None = None) -> list[Obstacle]:
    """What stands on the floor in one frame: the actors where the shot puts them (None: not in the scene), the
    rest where the scene has them, and the pillars. The ego is left out (its body is the BEV's blind spot)."""
    poses = poses or {}
    out = []
    for e in scene.actors():
        if e.role == "ego" or e.extent is None:
            continue
        pose = poses.get(e.name, e.pose) if e.name in poses else e.pose
        if pose is None:
            continue
        kind = e.kind or "vehicle"
        out.append(Obstacle(e.name, kind, pose, (e.extent[0] / 2, e.extent[1] / 2), float(e.extent[2])))
    for e in scene.entities:
        boxes = [s for s in e.shapes if isinstance(s, Box)]
        if e.role == "structure" and e.name.startswith("pillar_") and boxes:
            # its widest part (a wrap, a base) and its top: a pillar is drawn as several boxes about its axis
            half = (max(b.size[0] for b in boxes) / 2, max(b.size[1] for b in boxes) / 2)
            top = max(b.offset.z + b.size[2] / 2 for b in boxes)
            out.append(Obstacle(e.name, "pillar", e.pose, half, float(top)))
    return out


def camera_pixel(cam: CameraSpec, ego: Pose, point) -> tuple[float, float] | None:
    """Where a camera on the ego images a world point, None where it does not see it."""
    local = to_camera(camera_to_world(ego, cam), np.asarray(point, float).reshape(1, 3))
    lens = lens_of(cam)
    if cam.fisheye:
        theta = math.atan2(math.hypot(local[0, 1], local[0, 2]), local[0, 0])
        if theta > lens.theta_max:
            return None
        u, v = lens.project(local)
    else:
        if local[0, 0] <= cam.near:
            return None
        u, v = lens.pixels(local)
    u, v = float(u[0]), float(v[0])
    return (u, v) if 0 <= u < cam.width and 0 <= v < cam.height else None


def slot_truth(world: list[WorldBay], spec: BevSpec, ego: Pose, cameras: list[CameraSpec], maps: BevMaps,
               standing: list[Obstacle]) -> SlotTruth:
    """The BEV frame's ground truth for an ego at `ego`. Bays with no corner inside the BEV are left out."""
    w, h = spec.size
    by_name = {c.name: c for c in cameras}
    points: list[MarkingPoint] = []
    index: dict[tuple[float, float], int] = {}
    truth = SlotTruth(SlotFrame(points, [], spec.meters_per_pixel, (w, h)))
    for bay in world:
        px = spec.world_to_pixel(ego, np.array(bay.corners))
        inside = [(0 <= u < w and 0 <= v < h) for u, v in px]
        if not any(inside):
            continue
        direction = spec.world_direction(ego, bay.into)
        ids = []
        for k in (0, 1):  # the entrance's marking points, shared with the neighbouring bay
            key = (round(bay.corners[k][0], 4), round(bay.corners[k][1], 4))
            if key not in index:
                index[key] = len(points)
                points.append(MarkingPoint(float(px[k, 0]), float(px[k, 1]), direction, bay.shapes[k]))
            ids.append(index[key])
        vis, cams = [], {c.name: [] for c in cameras}
        for (x, y), (u, v), ok, paint in zip(bay.corners, px, inside, bay.paint):
            corner = np.array([x, y, 0.0])
            owner = int(maps.owner[int(v), int(u)]) if ok else -1
            if owner < 0:
                vis.append("outside")
            else:
                cam = by_name[maps.cameras[owner]]
                eye = camera_to_world(ego, cam)[:3, 3]
                if any(o.blocks(eye, corner) for o in standing):
                    vis.append("hidden")
                else:
                    vis.append("worn" if paint < WORN else "visible")
            for c in cameras:
                cams[c.name].append(camera_pixel(c, ego, corner))
        occupied = any(o.kind == "vehicle" and _inside(o.pose.x, o.pose.y, bay.corners) for o in standing)
        truth.frame.slots.append(Slot(ids[0], ids[1], tuple((float(u), float(v)) for u, v in px), occupied,
                                      bay=bay.bay))
        truth.visibility.append(tuple(vis))
        truth.in_cameras.append(cams)
    return truth


def _inside(x: float, y: float, quad) -> bool:
    """Whether (x, y) lies within a convex quad (either winding)."""
    signs = []
    for (ax, ay), (bx, by) in zip(quad, quad[1:] + quad[:1]):
        signs.append((bx - ax) * (y - ay) - (by - ay) * (x - ax))
    return all(s >= 0 for s in signs) or all(s <= 0 for s in signs)
