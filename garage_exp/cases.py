"""The research's cases as shot lists: where the ego, its target and every other vehicle stand in each frame.

A case names plan features (the corner nearest the entrance, a bay beside a pillar, a straight lane with
bays), found by the plan model, so it runs on any plan that has them. Distances are metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from garage_exp.errors import GarageError
from garage_exp.plan.classify import Classified
from garage_exp.plan.features import UNIT, corner_nearest_entrance, entrance_distance, longest_straight_run
from garage_exp.plan.model import YAW
from garage_exp.scene.bays import Bay, bays, pillar_centre
from garage_exp.scene.description import Entity, Mesh, Pose

EGO = "ego"


@dataclass
class Shot:
    """One frame: the ego's pose, the pose of each case vehicle (None: not in the scene), the target."""

    index: int
    label: str  # the variant this frame belongs to: a colour, a placement ("far=large"), ...
    position: float  # the plot's x value: the moving vehicle's distance along its path
    ego: Pose
    poses: dict[str, Pose | None]
    target: str


@dataclass
class CaseSetup:
    vehicles: list[Entity]  # the case's vehicles (ego included)
    shots: list[Shot]
    occluder: str | None = None  # the structure entity the case is about (a pillar)
    used_bays: list[tuple[int, int, int]] = field(default_factory=list)  # (i, j, k) kept free of parked cars
    position_label: str = "position (m)"


def vehicle_entity(name: str, role: str, model, pose: Pose = Pose()) -> Entity:
    return Entity(name=name, role=role, pose=pose, shapes=[Mesh(model.glb)], model=model.name,
                  size_class=model.size_class, extent=(model.length, model.width, model.height), static=False)


def steps(start: float, end: float, step: float) -> list[float]:
    """start, start +- step, ... up to end inclusive (either direction)."""
    if step <= 0:
        raise GarageError(f"step must be positive, got {step}", "case.step")
    n = int(math.floor(abs(end - start) / step + 1e-9))
    sign = 1.0 if end >= start else -1.0
    return [round(start + sign * k * step, 6) for k in range(n + 1)]


def _targets(cfg, library, rng, exclude=()):
    """One medium target car per palette colour (or the palette's named model)."""
    out = {}
    pinned = dict(cfg.palette.get("target_models") or {})
    for colour in cfg.palette.target_colours:
        if cfg.palette.target:
            model = library.get(cfg.palette.target)
        elif colour in pinned:
            model = library.get(pinned[colour])
        else:
            model = library.choose(size_class="medium", colour=colour, max_height=cfg.garage.ceiling_height - 0.1,
                                   kind="car", rng=rng)
        out[colour] = model
    return out


def _ego(cfg, library):
    return library.get(cfg.palette.ego)


def corner_case(cfg, classified: Classified, library, rng) -> CaseSetup:
    """Case 1: the ego approaches the corner nearest the entrance; the target waits beyond the bend."""
    c = cfg.case
    corner = corner_nearest_entrance(classified)
    cx, cy = classified.plan.cell_center(corner.cell.i, corner.cell.j)
    u, v = UNIT[corner.approach], UNIT[corner.exit]
    ego_model = _ego(cfg, library)
    targets = _targets(cfg, library, rng)
    longest = max(m.length for m in targets.values())
    room = corner.approach_length - ego_model.length / 2 - 0.2
    start, end = min(c.start, room), c.end
    if start < end:
        raise GarageError(f"the lane before the corner is {corner.approach_length:.1f} m; case.start={c.start} "
                          f"and case.end={c.end} do not fit", "case")
    ahead = min(c.target_distance, corner.exit_length - longest / 2 - 0.2)
    vehicles = [vehicle_entity(EGO, "ego", ego_model)]
    target_pose = Pose(cx + ahead * v[0], cy + ahead * v[1], 0.0, YAW[corner.exit])
    for colour, model in targets.items():
        vehicles.append(vehicle_entity(f"target_{colour}", "target", model))
    shots = []
    for colour in targets:
        for d in steps(start, end, c.step):
            ego = Pose(cx - d * u[0], cy - d * u[1], 0.0, YAW[corner.approach])
            poses = {f"target_{k}": (target_pose if k == colour else None) for k in targets}
            shots.append(Shot(len(shots), colour, d, ego, poses, f"target_{colour}"))
    return CaseSetup(vehicles, shots, occluder=f"pillar_{corner.pillar.a}_{corner.pillar.b}",
                     position_label="ego distance to the corner (m)")


def bay_beside_pillar(classified: Classified, garage) -> tuple[Bay, object, str]:
    """A Type3 bay facing a straight lane with a pillar at one of its lane-side corners, nearest the
    entrance. Returns the bay, the pillar, and the lane direction (N/E/S/W) from the bay."""
    plan = classified.plan
    dist = entrance_distance(plan)
    found = []
    for bay in bays(classified, garage):
        if bay.type != "type3":
            continue
        side = min(YAW, key=lambda d: abs(((YAW[d] - bay.yaw) + 180) % 360 - 180))
        u = UNIT[side]
        lane_cell = plan.cell_at(bay.x + u[0] * (bay.depth / 2 + 0.5), bay.y + u[1] * (bay.depth / 2 + 0.5))
        if lane_cell is None or classified.cell(*lane_cell).type != "straight":
            continue
        front = (bay.x + u[0] * bay.depth / 2, bay.y + u[1] * bay.depth / 2)
        perp = (-u[1], u[0])
        for pillar in classified.pillars:
            px, py = pillar_centre(plan, pillar, garage.pillar_size)
            for s in (-1, 1):
                cx, cy = front[0] + s * perp[0] * bay.width / 2, front[1] + s * perp[1] * bay.width / 2
                if math.hypot(px - cx, py - cy) <= garage.pillar_size:
                    found.append((dist[lane_cell], bay.i, bay.j, bay.index, bay, pillar, side))
    if not found:
        raise GarageError("no Type3 bay facing a straight lane with a pillar beside it (case 2 needs one)",
                          plan.source)
    found.sort(key=lambda t: t[:4])
    _, _, _, _, bay, pillar, side = found[0]
    return bay, pillar, side


def pass_case(cfg, classified: Classified, library, rng) -> CaseSetup:
    """Case 2: the ego is parked nose to the lane beside a pillar; a car passes in the lane ahead."""
    from garage_exp.plan.features import run_length

    c = cfg.case
    plan = classified.plan
    bay, pillar, side = bay_beside_pillar(classified, cfg.garage)
    u = UNIT[side]
    ego_model = _ego(cfg, library)
    targets = _targets(cfg, library, rng)
    gap = float(c.params.get("bumper_gap", 0.3))  # the ego's bumper this far behind the bay line
    if not 0.0 <= gap <= bay.depth - ego_model.length:
        raise GarageError(f"bumper_gap {gap} m does not fit a {ego_model.length:.1f} m ego in a {bay.depth:.1f} m "
                          "bay", "case.params.bumper_gap")
    inset = bay.depth / 2 - ego_model.length / 2 - gap
    ego = Pose(bay.x + u[0] * inset, bay.y + u[1] * inset, 0.0, YAW[side])
    lane_i, lane_j = plan.cell_at(bay.x + u[0] * (bay.depth / 2 + 0.5), bay.y + u[1] * (bay.depth / 2 + 0.5))
    lx, ly = plan.cell_center(lane_i, lane_j)
    # Drive direction: left to right as the ego sees it (perpendicular to its heading).
    left = {"E": "N", "N": "W", "W": "S", "S": "E"}[side]
    right = {"N": "S", "S": "N", "E": "W", "W": "E"}[left]
    w = UNIT[right]
    # The lane centre line passes the bay's axis at (ax, ay).
    if side in "EW":
        ax, ay = lx, bay.y
    else:
        ax, ay = bay.x, ly
    half = max(m.length for m in targets.values()) / 2 + 0.2
    lo = -run_length(plan, lane_i, lane_j, left) + half
    hi = run_length(plan, lane_i, lane_j, right) - half
    start, end = max(c.start, lo), min(c.end, hi)
    if start >= end:
        raise GarageError(f"the lane in front of the bay is too short for case.start={c.start}, case.end={c.end}",
                          "case")
    vehicles = [vehicle_entity(EGO, "ego", ego_model)]
    for colour, model in targets.items():
        vehicles.append(vehicle_entity(f"target_{colour}", "moving", model))
    shots = []
    for colour in targets:
        for s in steps(start, end, c.step):
            pose = Pose(ax + s * w[0], ay + s * w[1], 0.0, YAW[right])
            poses = {f"target_{k}": (pose if k == colour else None) for k in targets}
            shots.append(Shot(len(shots), colour, s, ego, poses, f"target_{colour}"))
    return CaseSetup(vehicles, shots, occluder=f"pillar_{pillar.a}_{pillar.b}", used_bays=[(bay.i, bay.j, bay.index)],
                     position_label="passing car's offset along the lane (m)")


def _run_bays(classified, garage, run):
    """Bays beside the run on its first bay side, ordered in driving direction, and the run's geometry."""
    side = run.bay_sides[0]
    cells = {(c.i, c.j) for c in run.cells}
    u = UNIT[side]
    h = UNIT[run.heading]
    plan = classified.plan
    out = []
    for bay in bays(classified, garage):
        lane = plan.cell_at(bay.x - u[0] * (bay.depth / 2 + 0.5), bay.y - u[1] * (bay.depth / 2 + 0.5))
        # a bay on `side` of the run faces back towards the lane (its yaw points opposite to `side`)
        if lane in cells and abs(((bay.yaw - YAW[side]) + 180) % 360 - 180) > 90:
            out.append(bay)
    out.sort(key=lambda b: b.x * h[0] + b.y * h[1])
    first = run.cells[0]
    x0, y0 = plan.cell_center(first.i, first.j)
    return out, side, (x0, y0), h


def parked_case(cfg, classified: Classified, library, rng) -> CaseSetup:
    """Case 3: parked cars of three sizes in the close, medium and far bays beside a straight lane."""
    c = cfg.case
    run = longest_straight_run(classified)
    run_bays, side, (x0, y0), h = _run_bays(classified, cfg.garage, run)
    slots = dict(c.params.get("distances", {"close": 1, "medium": 2, "far": 3}))
    if not run_bays or max(slots.values()) >= len(run_bays):
        raise GarageError(f"the straight lane has {len(run_bays)} bays on its {side} side; case 3 needs "
                          f"{max(slots.values()) + 1}", classified.plan.source)
    close = run_bays[slots["close"]]
    t_close = close.x * h[0] + close.y * h[1]
    # Lane centre line: the run's cells' centre across the axis.
    across = (x0, y0)
    ego_model = _ego(cfg, library)
    ceiling = cfg.garage.ceiling_height - 0.1
    colour = cfg.palette.target_colours[0] if cfg.palette.target_colours else None
    vehicles = [vehicle_entity(EGO, "ego", ego_model)]
    names: dict[tuple[str, str], str] = {}
    for placement in c.placements:
        for where, size in dict(placement).items():
            if where not in slots:
                raise GarageError(f"unknown bay {where!r} (have {sorted(slots)})", "case.placements")
            if (where, size) in names:
                continue
            bay = run_bays[slots[where]]
            fit = dict(size_class=size, max_height=ceiling, max_length=bay.depth + 0.3, rng=rng)
            try:
                model = library.choose(colour=colour, **fit)
            except GarageError:  # no model of that size in the target colour: any colour
                model = library.choose(**fit)
            name = f"{where}_{size}"
            names[(where, size)] = name
            # Parked nose to the lane, centred in the bay.
            vehicles.append(vehicle_entity(name, "parked", model, Pose(bay.x, bay.y, 0.0, bay.yaw)))
    if not names:
        raise GarageError("case 3 needs at least one placement", "case.placements")
    order = sorted(slots, key=slots.get)
    shots = []
    for placement in c.placements:
        placement = dict(placement)
        label = ",".join(f"{k}={placement[k]}" for k in order if k in placement)
        target_where = max(placement, key=lambda k: slots[k])
        present = {names[(k, v)] for k, v in placement.items()}
        for d in steps(c.start, c.end, c.step):
            t = t_close - d
            ego = Pose(across[0] * (1 - abs(h[0])) + t * h[0], across[1] * (1 - abs(h[1])) + t * h[1], 0.0,
                       YAW[run.heading])
            poses = {e.name: (e.pose if e.name in present else None) for e in vehicles[1:]}
            shots.append(Shot(len(shots), label, d, ego, poses, names[(target_where, placement[target_where])]))
    used = [(b.i, b.j, b.index) for b in run_bays[: max(slots.values()) + 1]]
    return CaseSetup(vehicles, shots, used_bays=used, position_label="ego distance to the close bay (m)")


def light_case(cfg, classified: Classified, library, rng) -> CaseSetup:
    """The lighting case: black and white cars unoccluded in the lane ahead of a static ego."""
    c = cfg.case
    run = longest_straight_run(classified)
    plan = classified.plan
    first = run.cells[0]
    x0, y0 = plan.cell_center(first.i, first.j)
    h = UNIT[run.heading]
    ego_model = _ego(cfg, library)
    targets = _targets(cfg, library, rng)
    distances = list(c.params.get("distances", [c.target_distance]))
    run_len = sum(float(plan.C[x.j] if run.heading == "E" else plan.R[x.i]) for x in run.cells)
    back = -float(plan.C[first.j] if run.heading == "E" else plan.R[first.i]) / 2 + ego_model.length / 2 + 0.3
    if back + max(distances) + 2.5 > run_len:
        raise GarageError(f"the straight lane ({run_len:.1f} m) is too short for a target {max(distances)} m "
                          "ahead", "case.target_distance")
    ego = Pose(x0 + back * h[0], y0 + back * h[1], 0.0, YAW[run.heading])
    vehicles = [vehicle_entity(EGO, "ego", ego_model)]
    for colour, model in targets.items():
        vehicles.append(vehicle_entity(f"target_{colour}", "target", model))
    shots = []
    for colour in targets:
        for d in distances:
            pose = Pose(ego.x + d * h[0], ego.y + d * h[1], 0.0, YAW[run.heading])
            poses = {f"target_{k}": (pose if k == colour else None) for k in targets}
            shots.append(Shot(len(shots), colour, float(d), ego, poses, f"target_{colour}"))
    return CaseSetup(vehicles, shots, position_label="target distance (m)")


CASES = {"corner": corner_case, "pass": pass_case, "parked": parked_case, "light": light_case}


def make_case(cfg, classified: Classified, library, rng: np.random.Generator) -> CaseSetup:
    try:
        build = CASES[cfg.case.kind]
    except KeyError:
        raise GarageError(f"unknown case kind {cfg.case.kind!r} (have {sorted(CASES)})", "case.kind") from None
    return build(cfg, classified, library, rng)
