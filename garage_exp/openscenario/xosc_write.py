"""A job's scenario as ASAM OpenSCENARIO 1.2 (`scenario.xosc`) with the garage's driving lanes as ASAM OpenDRIVE
(`garage.xodr`), written with `scenariogeneration`, for the tools test engineers replay scenarios in (esmini,
CARLA's ScenarioRunner, commercial simulators, HIL rigs).

What is written (docs/openscenario.md has the mapping; tests/test_esmini.py replays it in esmini):
- entities: every actor of the variant as a Vehicle (category car/van/bus/truck from its model), a Pedestrian or a
  MiscObject (a box: an obstacle), with its bounding box (our extent) and Properties saying what garage_exp made
  it from (role, kind, model, age, height). A vehicle's reference point is its rear axle, as OpenSCENARIO has it
  (REAR_AXLE_IN from its rear bumper; the bounding box's centre lies `axle_offset` ahead of it); a person's or a
  box's is its footprint's centre;
- the parameters EgoSpeed (m/s, negative when it reverses) and, for an ego in a lane, EgoS and EgoOffset (its
  start along its road and its offset from its lane's centre);
- initial positions: the ego in a declared lane (`ego_lane`: LanePosition on its road, in the lane its side of
  the centre line says under the roads' declared traffic rule), every other actor in the lane that holds it (a
  driving lane, or the outer lane beside it: a bay), else a WorldPosition (x, y in the plan's world frame, which
  is the .xodr's inertial frame; heading in radians, counter-clockwise from +x, as our yaw);
- motion: the ego drives its lane (AssignRouteAction) at EgoSpeed from the start; every other mover follows a
  polyline trajectory from its start to its end (a walk across a lane crosses it), paced by speed actions: an
  actor moving along with the ego (`case.motion.along`) starts when the ego has travelled to `at`
  (TraveledDistanceCondition on the ego) and accelerates as the case says (a `linear` change at a `rate`), one
  already under way at the first frame starts at the speed it has there; any other mover starts at the
  simulation time of its first move. Each stops (speed 0) when it has travelled its track;
- the storyboard stops one second after every mover has travelled its track (600 s at the latest).

One file per variant of the case (replicate 0): `scenario.xosc` for the first, `scenario_2.xosc`, ... for the
others. A case whose ego stands still sweeps a placement value frame by frame rather than in time; it is written
as the moved actor travelling through its placements at a nominal speed (1.4 m/s for people, `ego.speed` for
others), and the FileHeader's description says so.

The lanes: one OpenDRIVE road per maximal straight run of driveable cells along a row or a column between junction
cells, through the cells' centres from edge to edge, with one driving lane each side (half the cell's width each)
and beyond each an outer lane as deep as the neighbouring row or column (parking beside bays, none beside walls).
Each corner, T-junction and crossroads cell is an OpenDRIVE junction whose one-way connecting roads (straight across
it, and turns) link the roads that end at its edges (write_xodr).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from garage_exp.core.errors import GarageError
from garage_exp.plan.model import OPPOSITE, YAW
from garage_exp.scene.description import Entity, Pose

OSC_MINOR = 2
AUTHOR = "garage_exp"
PREFIX = "garage_exp."  # Properties keys carrying what an entity was made from (read back by the importer)
CATEGORIES = {"car": "car", "suv": "car", "pickup": "van", "van": "van", "bus": "bus", "truck": "truck"}


@dataclass(frozen=True)
class ExportInfo:
    """What the files say about the job besides its tracks (built from the job's config by run/openscenario.py):
    the version written, the names and values in each scenario's description, the garage's dimensions."""

    version: str  # export.openscenario_version
    case: str
    site: str
    step: float  # case.motion.step: a variant's step when its frames do not say one
    plan: str
    light: str
    ego_speed: float  # km/h
    pillar_size: float
    ceiling_height: float
    wall_thickness: float


@dataclass
class Track:
    """One actor in one variant: where it starts and, if it moves, where it ends, how fast and from when."""

    name: str
    entity: Entity
    start: Pose
    end: Pose | None = None  # None: it stands still
    speed: float = 0.0  # m/s
    trigger: tuple[str, float] = ("time", 0.0)  # ("time", s) | ("ego_travel", m travelled by the ego)
    accelerate: float = 0.0  # metres from standstill to `speed` at a constant acceleration (0: a step)
    initial: float = 0.0  # m/s it already has at the start (a walk under way at the first frame)
    meet: Pose | None = None  # where the ego is when this actor reaches its end (a timed arrival: `meet`)

    @property
    def length(self) -> float:
        return math.hypot(self.end.x - self.start.x, self.end.y - self.start.y) if self.end else 0.0

    @property
    def velocity(self) -> float:
        """Its speed, negative when it moves against its heading (a reversing ego, as OpenSCENARIO says it)."""
        if self.end is None:
            return 0.0
        h = math.radians(self.start.yaw)
        ahead = (self.end.x - self.start.x) * math.cos(h) + (self.end.y - self.start.y) * math.sin(h)
        return -self.speed if ahead < -1e-9 else self.speed


@dataclass
class Run:
    """A maximal straight run of driveable cells between junction cells (one OpenDRIVE road), or the straight way
    through one junction cell (a connecting road of that junction: `junction` > 0)."""

    start: tuple[float, float]
    heading: float  # radians: 0 along a row (E), pi/2 up a column (N)
    length: float
    width: float  # across: the cells' depth (a row's R or a column's C)
    cells: list[tuple[int, int]]  # in the order the road runs
    sides: tuple[float, float]  # the depth of the row or column on its left and on its right (0: none)
    junction: int = 0  # the junction (1, 2, ...) whose connecting road it is; 0: an ordinary road
    side: int = 0  # a connecting road's lanes: -1 the right ones only, 1 the left ones only (one way); 0 both

    def has(self, lane: int) -> bool:
        """Whether the road has lanes on lane id `lane`'s side."""
        return self.side == 0 or (lane > 0) == (self.side > 0)

    def st(self, x: float, y: float) -> tuple[float, float]:
        """(s, t) of a world point on this road's reference line."""
        c, n = math.cos(self.heading), math.sin(self.heading)
        return (x - self.start[0]) * c + (y - self.start[1]) * n, -(x - self.start[0]) * n + (y - self.start[1]) * c


JUNCTION_TYPES = ("corner", "t_junction", "crossroads")


def junction_cells(classified) -> dict[tuple[int, int], int]:
    """The driveable cells where lanes meet (corners, T-junctions, crossroads; plan/classify.py) and each one's
    junction id (1, 2, ... in row-major order)."""
    cells = [(c.i, c.j) for c in classified.all_cells() if c.driveable and c.type in JUNCTION_TYPES]
    return {cell: k for k, cell in enumerate(cells, start=1)}


def lane_runs(classified) -> list[Run]:
    """The straight roads, their index + 1 their road id: maximal straight runs of driveable cells along rows
    (heading E) and columns (heading N) cut at junction cells, then the straight ways across each junction cell
    along a row and a column (its connecting roads, heading E or N as the roads they join, one way each: a pair per
    axis, one with the right lanes and one with the left; across a dead end too, so that whoever stands in a
    corner is on a lane)."""
    plan = classified.plan
    m, n = plan.shape
    junctions = junction_cells(classified)
    runs = []

    def ordinary(cell) -> bool:
        return cell.driveable and (cell.i, cell.j) not in junctions

    def connected(a, b, d) -> bool:
        return ordinary(a) and ordinary(b) and d in a.lanes

    def row(i, j, k, junction=0, side=0) -> Run:
        y = plan.cell_center(i, j)[1]
        sides = (float(plan.R[i - 1]) if i > 0 else 0.0, float(plan.R[i + 1]) if i + 1 < m else 0.0)
        return Run((float(plan.x_edges[j]), y), 0.0, float(plan.x_edges[k + 1] - plan.x_edges[j]),
                   float(plan.R[i]), [(i, c) for c in range(j, k + 1)], sides, junction, side)

    def column(j, i, k, junction=0, side=0) -> Run:  # from row i (the bottom) up to row k
        x = plan.cell_center(i, j)[0]
        sides = (float(plan.C[j - 1]) if j > 0 else 0.0, float(plan.C[j + 1]) if j + 1 < n else 0.0)
        return Run((x, float(plan.y_edges[i + 1])), math.pi / 2, float(plan.y_edges[k] - plan.y_edges[i + 1]),
                   float(plan.C[j]), [(r, j) for r in range(i, k - 1, -1)], sides, junction, side)

    for i in range(m):
        j = 0
        while j < n:
            cell = classified.cell(i, j)
            if not (ordinary(cell) and ({"E", "W"} & set(cell.lanes))):
                j += 1
                continue
            k = j
            while k + 1 < n and connected(classified.cell(i, k), classified.cell(i, k + 1), "E"):
                k += 1
            runs.append(row(i, j, k))
            j = k + 1
    for j in range(n):
        i = m - 1
        while i >= 0:  # from the bottom row up: heading N
            cell = classified.cell(i, j)
            if not (ordinary(cell) and ({"N", "S"} & set(cell.lanes))):
                i -= 1
                continue
            k = i
            while k - 1 >= 0 and connected(classified.cell(k, j), classified.cell(k - 1, j), "N"):
                k -= 1
            runs.append(column(j, i, k))
            i = k - 1
    for (i, j), junction in junctions.items():
        lanes = set(classified.cell(i, j).lanes)
        for side in (-1, 1):  # one way each: the right lanes' traffic and the left lanes'
            if {"E", "W"} & lanes:  # through the cell, or from a dead end (a corner's, a T's stem axis) to its arm
                runs.append(row(i, j, j, junction, side))
            if {"N", "S"} & lanes:
                runs.append(column(j, i, i, junction, side))
    return runs


def _side_types(classified, run: Run) -> list[tuple[float, str, str]]:
    """Where along the road the cells beside it change: (s, left type, right type), OpenDRIVE lane types of the
    outer lanes (parking beside bays and free space, none beside walls, obstacles and other lanes)."""
    plan = classified.plan
    m, n = plan.shape
    di, dj = (-1, 0) if run.heading == 0.0 else (0, -1)  # the left neighbour: N of a row, W of a column

    def kind(i, j) -> str:
        if not (0 <= i < m and 0 <= j < n):
            return "none"
        cell = classified.cell(i, j)
        return "parking" if cell.value == 0 else "none"

    out, s = [], 0.0
    for i, j in run.cells:
        types = (kind(i + di, j + dj), kind(i - di, j - dj))
        if not out or out[-1][1:] != types:
            out.append((s, *types))
        s += float(plan.C[j]) if run.heading == 0.0 else float(plan.R[i])
    return out


@dataclass
class Thing:
    """A fixed thing of the garage as an OpenDRIVE object: its centre, heading (radians), size, type."""

    kind: str  # OpenDRIVE object type: pole (a pillar), barrier (a wall), building (an obstacle cell), parkingSpace
    name: str
    x: float
    y: float
    hdg: float
    length: float
    width: float
    height: float


def garage_things(classified, pillar_size: float = 0.6, height: float = 2.8, wall: float = 0.25) -> list[Thing]:
    """The pillars, the perimeter walls, the obstacle cells and the bays (parking cells beside a lane) of the
    plan, with their dimensions."""
    from garage_exp.plan.draw import _perimeter_walls

    plan = classified.plan
    out = []
    for k, p in enumerate(classified.pillars):
        x, y = plan.vertex(p.a, p.b)
        out.append(Thing("pole", f"pillar_{k}", x + p.sx * pillar_size / 2, y + p.sy * pillar_size / 2, 0.0,
                         pillar_size, pillar_size, height))
    for k, ((x0, y0), (x1, y1)) in enumerate(_perimeter_walls(classified)):
        out.append(Thing("barrier", f"wall_{k}", (x0 + x1) / 2, (y0 + y1) / 2, math.atan2(y1 - y0, x1 - x0),
                         math.hypot(x1 - x0, y1 - y0), wall, height))
    for cell in classified.all_cells():
        if cell.value == -1 or (cell.value == 0 and cell.lanes):
            x0, y0, x1, y1 = plan.cell_rect(cell.i, cell.j)
            kind, name = ("building", "obstacle") if cell.value == -1 else ("parkingSpace", "bay")
            out.append(Thing(kind, f"{name}_{cell.i}_{cell.j}", (x0 + x1) / 2, (y0 + y1) / 2, 0.0, x1 - x0, y1 - y0,
                             height if cell.value == -1 else 0.0))
    return out


def _add_objects(odr, roads: list, runs: list[Run], things: list[Thing]) -> None:
    """Each thing on the road nearest its centre (s clamped to the road, t across it, heading relative)."""
    import numpy as np
    from scenariogeneration import xodr

    # Every road's distance to a thing at once (a large plan: thousands of things x a hundred roads), with
    # Run.st's operations in its order (math's cos and sin), so the nearest road is the one it picks one by one
    # (argmin: the first of equals, as min does).
    sx, sy = np.array([r.start[0] for r in runs]), np.array([r.start[1] for r in runs])
    c, n = np.array([math.cos(r.heading) for r in runs]), np.array([math.sin(r.heading) for r in runs])
    length = np.array([r.length for r in runs])
    for th in things:
        dx, dy = th.x - sx, th.y - sy
        s, t = dx * c + dy * n, -dx * n + dy * c
        near = int(np.argmin(np.maximum(np.maximum(-s, s - length), 0.0) + np.abs(t)))
        s, t = runs[near].st(th.x, th.y)
        obj = xodr.Object(round(min(max(s, 0.0), runs[near].length), 6), round(t, 6),
                          Type=getattr(xodr.ObjectType, th.kind), subtype=th.name.split("_")[0],
                          name=th.name,
                          hdg=round(th.hdg - runs[near].heading, 9), length=round(th.length, 6),
                          width=round(th.width, 6), height=round(th.height, 6))
        roads[near].add_object(obj)


def _ends(run: Run) -> tuple[tuple[int, int], str, tuple[int, int], str]:
    """The cells before a road's start and after its end, and the direction from each back to the road."""
    (i0, j0), (i1, j1) = run.cells[0], run.cells[-1]
    if run.heading == 0.0:
        return (i0, j0 - 1), "E", (i1, j1 + 1), "W"
    return (i0 + 1, j0), "N", (i1 - 1, j1), "S"


def arms(runs: list[Run], junctions: dict) -> dict[tuple[tuple[int, int], str], tuple[int, str]]:
    """(junction cell, direction) -> (road id, the road's contact point there: start or end) of each ordinary road
    that ends at a junction cell."""
    out = {}
    for k, run in enumerate(runs, start=1):
        if run.junction:
            continue
        before, back, after, ahead = _ends(run)
        if before in junctions:
            out[before, back] = (k, "start")
        if after in junctions:
            out[after, ahead] = (k, "end")
    return out


@dataclass
class Turn:
    """A connecting road that turns through a junction cell from its arm `arms[0]` to `arms[1]`: a straight piece
    and a quarter circle (or the other way round) from one edge's centre to the other's (cells need not be
    square), its lanes widening from the one road's half width to the other's."""

    cell: tuple[int, int]
    arms: tuple[str, str]
    start: tuple[float, float]
    heading: float
    pieces: list[tuple[str, float, float]]  # ("line", length, 0) | ("arc", curvature, angle)
    widths: tuple[float, float]
    side: int  # its one lane: -1 the right, 1 the left

    @property
    def length(self) -> float:
        return sum(a if kind == "line" else b / abs(a) for kind, a, b in self.pieces)


def turns(classified) -> list[Turn]:
    """The turning connecting roads: a pair (one way each) per pair of perpendicular arms of each junction cell."""
    plan = classified.plan
    out = []
    for (i, j) in junction_cells(classified):
        x0, y0, x1, y1 = plan.cell_rect(i, j)
        xc, yc = plan.cell_center(i, j)
        edge = {"W": (x0, yc), "E": (x1, yc), "S": (xc, y0), "N": (xc, y1)}
        width = {d: float(plan.R[i]) if d in "EW" else float(plan.C[j]) for d in "NESW"}
        lanes = [d for d in "NESW" if d in classified.cell(i, j).lanes]
        for a, d1 in enumerate(lanes):
            for d2 in lanes[a + 1:]:
                if OPPOSITE[d1] == d2:
                    continue
                (px, py), (qx, qy) = edge[d1], edge[d2]
                h0 = math.radians(YAW[OPPOSITE[d1]])
                ahead = (qx - px) * math.cos(h0) + (qy - py) * math.sin(h0)
                side = -(qx - px) * math.sin(h0) + (qy - py) * math.cos(h0)
                r = min(ahead, abs(side))
                pieces = [("line", ahead - r, 0.0)] if ahead - r > 1e-9 else []
                pieces.append(("arc", math.copysign(1.0 / r, side), math.pi / 2))
                if abs(side) - r > 1e-9:
                    pieces.append(("line", abs(side) - r, 0.0))
                out += [Turn((i, j), (d1, d2), (px, py), h0, pieces, (width[d1], width[d2]), side) for side in (-1, 1)]
    return out


def _link_connecting(road, lane, side: int, forward: bool, junction, before, after) -> None:
    """A one-way connecting road's links: to the road at its start (`before`: road id, contact point) and at its
    end (`after`), its lane's (id `side`) links to theirs, and the junction's connection from the road its traffic
    comes from (`forward`: its traffic runs along s, from `before`)."""
    from scenariogeneration import xodr

    for link, end, other in (("predecessor", "start", before), ("successor", "end", after)):
        if other is None:
            continue
        rid, contact = other
        getattr(road, f"add_{link}")(xodr.ElementType.road, rid, getattr(xodr.ContactPoint, contact))
        theirs = side if contact != end else -side  # start to end keeps lane ids, start to start flips them
        lane.add_link(link, theirs)
        if forward == (end == "start"):
            connection = xodr.Connection(rid, road.id, getattr(xodr.ContactPoint, end))
            connection.add_lanelink(theirs, side)
            junction.add_connection(connection)


def write_xodr(classified, path: Path, rule: str = "RHT", things: list[Thing] | None = None) -> Path:
    """The plan's driving lanes as OpenDRIVE roads (lane_runs), in the world frame of the plan: a driving lane
    each side of the cells' centre line (half the cell's width), and beyond each an outer lane as deep as the
    neighbouring row or column, of type parking beside bays and free space, none beside walls (so that no bay
    and no one standing in it is off the road). `rule`: the traffic rule the roads declare (RHT or LHT).
    Each junction cell (corner, T-junction, crossroads) is an OpenDRIVE junction: the roads end at its edges and
    link to it, and its connecting roads (straight through it, and turns) link to them, lane by lane."""
    from scenariogeneration import xodr

    odr = xodr.OpenDrive(f"garage {classified.plan.name}", revMinor="7")
    traffic = getattr(xodr.TrafficRule, rule)
    runs, roads = lane_runs(classified), []
    cells = junction_cells(classified)
    touch = arms(runs, cells)
    junctions = {jid: xodr.Junction(f"cell {i} {j}", jid) for (i, j), jid in cells.items()}
    def forward(side: int) -> bool:  # a one-way road's traffic runs along s: RHT's right lanes, LHT's left
        return (side < 0) == (rule == "RHT")

    for k, run in enumerate(runs, start=1):
        planview = xodr.PlanView(run.start[0], run.start[1], run.heading)
        planview.add_geometry(xodr.Line(run.length))
        lanes = xodr.Lanes()
        for s, left_type, right_type in _side_types(classified, run):
            section = xodr.LaneSection(s, xodr.Lane(xodr.LaneType.none))
            driving = {}
            for side, add, depth, outer in ((-1, section.add_right_lane, run.sides[1], right_type),
                                            (1, section.add_left_lane, run.sides[0], left_type)):
                if not run.has(side):
                    continue
                driving[side] = xodr.Lane(xodr.LaneType.driving, a=run.width / 2)
                add(driving[side])
                if depth > 0:
                    add(xodr.Lane(getattr(xodr.LaneType, outer), a=depth))
            lanes.add_lanesection(section)
        road = xodr.Road(k, planview, lanes, road_type=run.junction or -1, rule=traffic)
        before, back, after, ahead = _ends(run)
        if run.junction:
            cell = run.cells[0]
            _link_connecting(road, driving[run.side], run.side, forward(run.side), junctions[run.junction],
                             touch.get((cell, OPPOSITE[back])), touch.get((cell, OPPOSITE[ahead])))
        else:
            if before in cells:
                road.add_predecessor(xodr.ElementType.junction, cells[before])
            if after in cells:
                road.add_successor(xodr.ElementType.junction, cells[after])
        roads.append(road)
        odr.add_road(road)
    for k, turn in enumerate(turns(classified), start=len(runs) + 1):
        planview = xodr.PlanView(turn.start[0], turn.start[1], turn.heading)
        for kind, a, b in turn.pieces:
            planview.add_geometry(xodr.Line(a) if kind == "line" else xodr.Arc(a, angle=b))
        (w0, w1), length = turn.widths, turn.length
        section = xodr.LaneSection(0, xodr.Lane(xodr.LaneType.none))
        lane = xodr.Lane(xodr.LaneType.driving, a=w0 / 2, b=(w1 - w0) / 2 / length)
        (section.add_right_lane if turn.side < 0 else section.add_left_lane)(lane)
        lanes = xodr.Lanes()
        lanes.add_lanesection(section)
        jid = cells[turn.cell]
        road = xodr.Road(k, planview, lanes, road_type=jid, rule=traffic)
        _link_connecting(road, lane, turn.side, forward(turn.side), junctions[jid],
                         touch.get((turn.cell, turn.arms[0])), touch.get((turn.cell, turn.arms[1])))
        odr.add_road(road)
    for junction in junctions.values():
        odr.add_junction(junction)
    _add_objects(odr, roads, runs, things if things is not None else garage_things(classified))
    odr.adjust_startpoints()  # the lanes' links are set above (adjust_roads_and_lanes would guess them again)
    path.parent.mkdir(parents=True, exist_ok=True)
    odr.write_xml(str(path))
    # the header's bounds: the plan's extent (scenariogeneration writes 0)
    from garage_exp.scenario.asam import parse

    tree = parse(path)
    width, depth = classified.plan.size
    tree.getroot().find("header").attrib.update(
        {"north": f"{depth:.6f}", "south": "0.0", "east": f"{width:.6f}", "west": "0.0"})
    tree.write(str(path), xml_declaration=True, encoding="utf-8")
    return path


REAR_AXLE_IN = 0.9  # m: a vehicle's rear axle this far in from its rear bumper (and the front axle from its front)


def axle_offset(entity: Entity) -> float:
    """How far the bounding box's centre lies ahead of the entity's OpenSCENARIO reference point: a vehicle's is
    its rear axle (OpenSCENARIO 1.2, 'Coordinate systems': the vehicle's reference point), a person's or a box's
    its footprint's centre."""
    if entity.kind in ("person", "box"):
        return 0.0
    return max(entity.extent[0] / 2 - REAR_AXLE_IN, 0.0)


def reference(pose: Pose, entity: Entity) -> Pose:
    """Our pose (the footprint's centre) as the entity's reference point."""
    back = axle_offset(entity)
    h = math.radians(pose.yaw)
    return Pose(pose.x - back * math.cos(h), pose.y - back * math.sin(h), 0.0, pose.yaw)


def _entity_object(track: Track, carla: bool = False):
    """The entity's object; `carla`: as ScenarioRunner spawns it (a blueprint as a vehicle's name and a
    pedestrian's model, the ego marked type=ego_vehicle)."""
    from scenariogeneration import xosc

    e = track.entity
    length, width, height = e.extent
    box = xosc.BoundingBox(width, length, height, axle_offset(e), 0.0, height / 2)
    props = {"role": e.role, "kind": e.kind or "vehicle", "model": e.model or ""}
    if e.kind == "person":
        props.update(age=e.size_class or "adult", height=f"{height:.3f}")
        # the body's spec name (assets/people.py BodySpec.name: age-gender-build-pose-<height>cm) says what it was
        # made from: the height asked for (a crouching body's box is lower), its pose, build and gender
        parts = (e.model or "").split("-")
        if len(parts) == 5 and parts[4].endswith("cm") and parts[4][:-2].isdigit():
            props.update(gender=parts[1], build=parts[2], pose=parts[3], height=f"{int(parts[4][:-2]) / 100:.2f}")
        model = CARLA_WALKERS.get(e.size_class or "adult", CARLA_WALKERS["adult"]) if carla else e.model or "pedestrian"
        obj = xosc.Pedestrian(track.name, 20.0 if e.size_class == "child" else 70.0, xosc.PedestrianCategory.pedestrian,
                              box, model=model)
    elif e.kind == "box":
        obj = xosc.MiscObject(track.name, 100.0, xosc.MiscObjectCategory.obstacle, box)
    else:
        from garage_exp.scene.kinds import kind_of

        body = kind_of(e.model or "")
        props["body"] = body
        props["size"] = e.size_class or ""
        wheel = 0.65 if body in ("car", "suv") else 0.8
        base = 2 * axle_offset(e)  # the wheelbase: both axles REAR_AXLE_IN from their bumpers
        name = CARLA_VEHICLES.get(body, CARLA_VEHICLES["car"]) if carla else track.name
        obj = xosc.Vehicle(name, getattr(xosc.VehicleCategory, CATEGORIES.get(body, "car")), box,
                           xosc.Axle(0.6, wheel, width * 0.85, base, wheel / 2),
                           xosc.Axle(0.0, wheel, width * 0.85, 0.0, wheel / 2), 30.0, 3.0, 8.0)
    for key, value in props.items():
        obj.add_property(PREFIX + key, str(value))
    if carla and e.role == "ego":
        obj.add_property("type", "ego_vehicle")
    return obj


def _position(pose: Pose, entity: Entity | None = None):
    """A WorldPosition of the entity's reference point (`entity` None: the pose as it is)."""
    from scenariogeneration import xosc

    p = reference(pose, entity) if entity is not None else pose
    return xosc.WorldPosition(round(p.x, 6), round(p.y, 6), 0.0, round(math.radians(p.yaw % 360.0), 9))


def _speed(value, accelerate: float = 0.0):
    """Reach `value` m/s (a number or a parameter reference) at once, or (accelerate > 0) at the constant
    acceleration that reaches it after `accelerate` metres from standstill (a `rate` of v^2 / 2a m/s^2)."""
    from scenariogeneration import xosc

    number = isinstance(value, (int, float))
    value = round(value, 6) if number else value
    if accelerate > 0 and value != 0 and number:
        return xosc.AbsoluteSpeedAction(value, xosc.TransitionDynamics(
            xosc.DynamicsShapes.linear, xosc.DynamicsDimension.rate, round(value * value / (2 * accelerate), 6)))
    return xosc.AbsoluteSpeedAction(value, xosc.TransitionDynamics(
        xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0))


def _synchronize(track: Track, ego: Track):
    """A timed arrival (`meet`) as OpenSCENARIO says it: reach the end as the ego reaches where the case meets
    it, at `speed` from `accelerate` metres on (the steady state); at another EgoSpeed the arrival still holds."""
    from scenariogeneration import xosc

    steady = xosc.TargetDistanceSteadyState(round(max(track.length - track.accelerate, 0.0), 6))
    return xosc.SynchronizeAction("ego", _position(track.meet, ego.entity), _position(track.end, track.entity),
                                  target_tolerance_master=0.05, target_tolerance=0.05,
                                  final_speed=xosc.AbsoluteSpeed(round(track.speed, 6), steady))


@dataclass
class EgoLane:
    """Where a driving ego is on the roads: the road (lane_runs' index + 1), the lane it drives in, the s of its
    reference point at its start and end, its offset from the lane's centre, and the traffic rule that makes that
    lane's driving direction its direction of travel (the side of the centre line it keeps to); `road_end`: the road
    it ends on (through junctions: the straight roads it drives are collinear, its lane id the same on each)."""

    road: int
    lane: int
    s0: float
    s1: float
    offset: float
    rule: str
    road_end: int = 0  # 0: `road`
    # where its route begins when it starts on a connecting road and ends beyond it: the next road's (id, s) where
    # it enters it (a route from a connecting road out of a dead end, which no road enters, is "not valid" in esmini)
    entry: tuple[int, float] | None = None

    @property
    def last(self) -> int:
        return self.road_end or self.road


def ego_lane(runs: list, track: Track) -> EgoLane | None:
    """The lane an ego keeps to, from where it stands and where it travels (standing: where it faces); None when
    it is not on the driving lanes of straight roads along one line (it then goes by world positions). An ego on
    the centre line (t = 0) is in the lane on its right under right-hand traffic, at that lane's left edge:
    declared, not left to rounding."""
    a = reference(track.start, track.entity)
    b = reference(track.end, track.entity) if track.end is not None else a
    travel = math.atan2(b.y - a.y, b.x - a.x) if track.end is not None else math.radians(track.start.yaw)

    def holding(p) -> list[tuple[int, float, float]]:
        out = []
        for k, run in enumerate(runs, start=1):
            if abs(math.sin(run.heading - travel)) > 1e-6:
                continue
            s, t = run.st(p.x, p.y)
            if -1e-6 <= s <= run.length + 1e-6 and abs(t) <= run.width / 2 + 1e-6:
                out.append((k, s, t))
        return out

    for k, s0, t0 in holding(a):
        run = runs[k - 1]
        along = 1 if math.cos(run.heading - travel) > 0 else -1  # travels towards +s or -s
        left = t0 * along > 1e-6
        lane = along if left else -along  # RHT: +s traffic in the right lanes (negative ids); LHT the left
        ends = [(e, s1) for e, s1, t1 in holding(b) if runs[e - 1].heading == run.heading
                and abs(t0 - t1) <= 1e-6 and runs[e - 1].has(lane)]
        ends.sort(key=lambda end: end[0] != k)  # its own road first
        if not run.has(lane) or not ends:
            continue
        end, s1 = ends[0]
        centre = math.copysign(run.width / 4, lane)
        entry = None
        if run.junction and end != k:  # the road it drives onto next, where it enters it
            c, n = math.cos(run.heading), math.sin(run.heading)
            s_out = run.length + 1e-3 if along > 0 else -1e-3
            x, y = run.start[0] + s_out * c - t0 * n, run.start[1] + s_out * n + t0 * c
            following = [(e, s) for e, s, _ in holding(Pose(x, y, 0.0, 0.0))
                         if e != k and runs[e - 1].heading == run.heading and runs[e - 1].has(lane)]
            if following:
                entry = (following[0][0], 0.0 if along > 0 else round(runs[following[0][0] - 1].length, 6))
        return EgoLane(k, lane, round(s0, 6), round(s1, 6), round(t0 - centre, 6), "LHT" if left else "RHT",
                       0 if end == k else end, entry)
    return None


def lane_of(runs: list, pose: Pose) -> tuple[int, int, float, float] | None:
    """(road, lane, s, offset from the lane's centre) of a reference point on the roads: in a driving lane where
    one holds it, else in an outer lane (a bay, the space beside the lane); None off every road."""
    found = None
    for k, run in enumerate(runs, start=1):
        s, t = run.st(pose.x, pose.y)
        if not -1e-6 <= s <= run.length + 1e-6:
            continue
        half = run.width / 2
        side = run.sides[0] if t > 0 else run.sides[1]
        lane = 1 if t > 1e-9 else -1
        if not run.has(lane):  # a one-way connecting road without lanes on this side
            continue
        if abs(t) <= half + 1e-9:
            return k, lane, round(s, 6), round(t - math.copysign(half / 2, lane), 6)
        if found is None and side > 0 and abs(t) <= half + side:
            lane = 2 if t > 0 else -2
            found = k, lane, round(s, 6), round(t - math.copysign(half + side / 2, t), 6)
    return found


def _start_position(runs: list, pose: Pose, entity: Entity):
    """Where an actor starts: a LanePosition in the lane that holds its reference point (esmini then reports it
    there, not as an offset from the nearest driving lane), else a WorldPosition."""
    on = lane_of(runs, reference(pose, entity))
    if on is None:
        return _position(pose, entity)
    road, lane, s, offset = on
    return _lane_position(s, offset, EgoLane(road, lane, s, s, offset, ""), pose.yaw)


def _lane_position(s, offset, lane: EgoLane, yaw: float):
    from scenariogeneration import xosc

    return xosc.LanePosition(s, offset, lane.lane, lane.road,
                             xosc.Orientation(h=round(math.radians(yaw % 360.0), 9),
                                              reference=xosc.ReferenceContext.absolute))


def write_xosc(info: ExportInfo, moving: list[Track], label: str, notes: list[str], path: Path, xodr_name: str,
               target: str = "", step: float | None = None, lane: EgoLane | None = None,
               runs: list | None = None, minor: int = OSC_MINOR) -> Path:
    """One variant's scenario. The ego drives its declared lane (`lane`; LanePositions with the parameters EgoS,
    EgoOffset) at the parameter EgoSpeed; every other mover follows a polyline trajectory from its start to its
    end, its pace set by speed actions; the stop trigger's time follows EgoSpeed."""
    from scenariogeneration import xosc

    runs = runs or []
    ego = next((t for t in moving if t.name == "ego"), None)
    ego_v = ego.velocity if ego is not None else 0.0
    params = xosc.ParameterDeclarations()
    params.add_parameter(xosc.Parameter("EgoSpeed", xosc.ParameterType.double, str(round(ego_v, 6))))
    if lane is not None:
        params.add_parameter(xosc.Parameter("EgoS", xosc.ParameterType.double, str(lane.s0)))
        params.add_parameter(xosc.Parameter("EgoOffset", xosc.ParameterType.double, str(lane.offset)))
    entities = xosc.Entities()
    init = xosc.Init()
    for t in moving:
        entities.add_scenario_object(t.name, _entity_object(t, carla=minor == 0))
        if t.name == "ego" and lane is not None:
            init.add_init_action(t.name, xosc.TeleportAction(_lane_position("$EgoS", "$EgoOffset", lane, t.start.yaw)))
            if t.end is None:
                continue
            route = xosc.Route("ego_route")
            first = _lane_position("$EgoS", "$EgoOffset", lane, t.start.yaw) if lane.entry is None else \
                _lane_position(lane.entry[1], "$EgoOffset", EgoLane(lane.entry[0], lane.lane, 0, 0, 0, ""), t.start.yaw)
            route.add_waypoint(first, xosc.RouteStrategy.shortest)
            # on its own road the end follows EgoS (1.0 has no expressions); on a road beyond a junction it is fixed
            end = f"${{$EgoS + {lane.s1 - lane.s0:.6f}}}" if minor > 0 and lane.last == lane.road else lane.s1
            route.add_waypoint(_lane_position(end, "$EgoOffset", EgoLane(lane.last, lane.lane, 0, 0, 0, ""),
                                              t.end.yaw), xosc.RouteStrategy.shortest)
            init.add_init_action(t.name, xosc.AssignRouteAction(route))
            init.add_init_action(t.name, _speed("$EgoSpeed"))
            continue
        init.add_init_action(t.name, xosc.TeleportAction(_start_position(runs, t.start, t.entity)))
        if t.end is not None:
            # a polyline from its start to its end (a route would keep it on a lane: a walk across it would be a
            # slide along it); its speed actions pace it (timing none)
            # (1.0 wants each vertex's time; with no time reference a player ignores it)
            times = [] if minor > 0 else [0.0, round((t.length + t.accelerate) / t.speed if t.speed else 0.0, 6)]
            shape = xosc.Polyline(times, [_position(t.start, t.entity), _position(t.end, t.entity)])
            trajectory = xosc.Trajectory(f"{t.name}_path", False)
            trajectory.add_shape(shape)
            init.add_init_action(t.name, xosc.FollowTrajectoryAction(trajectory, xosc.FollowingMode.position))
            if t.initial > 0:
                init.add_init_action(t.name, _speed(t.initial))
            elif t.trigger == ("time", 0.0):
                init.add_init_action(t.name, _speed("$EgoSpeed" if t.name == "ego" else t.speed, t.accelerate))
    at_least = xosc.Rule.greaterOrEqual if minor >= 1 else xosc.Rule.greaterThan  # (1.0 has no greaterOrEqual)
    act = xosc.Act("motion", xosc.ValueTrigger("start", 0, xosc.ConditionEdge.none,
                                               xosc.SimulationTimeCondition(0, at_least)))
    done = xosc.ConditionGroup("stop")
    priority = xosc.Priority.override if minor >= 2 else xosc.Priority.overwrite  # (renamed in 1.2)
    for t in moving:
        if t.end is None:
            continue
        maneuver = xosc.Maneuver(f"{t.name}_moves")
        if t.trigger != ("time", 0.0) or t.initial > 0:
            kind, value = t.trigger
            go = xosc.Event(f"{t.name}_starts", priority)
            synchronised = t.meet is not None and ego is not None and minor > 0  # 1.0: no steady state
            go.add_action(f"{t.name}_speed", _synchronize(t, ego) if synchronised else _speed(t.speed, t.accelerate))
            go.add_trigger(xosc.EntityTrigger(f"ego_travelled_{value:.2f}", 0, xosc.ConditionEdge.rising,
                                              xosc.TraveledDistanceCondition(round(value, 6)), "ego")
                           if kind == "ego_travel" else
                           xosc.ValueTrigger(f"time_{value:.2f}", 0, xosc.ConditionEdge.none,
                                             xosc.SimulationTimeCondition(round(value, 6), at_least)))
            maneuver.add_event(go)
        stop = xosc.Event(f"{t.name}_stops", priority)
        stop.add_action(f"{t.name}_stop", _speed(0.0))
        stop.add_trigger(xosc.EntityTrigger(f"{t.name}_travelled_{t.length:.2f}", 0, xosc.ConditionEdge.rising,
                                            xosc.TraveledDistanceCondition(round(t.length, 6)), t.name))
        maneuver.add_event(stop)
        group = xosc.ManeuverGroup(f"{t.name}_group")
        group.add_actor(t.name)
        group.add_maneuver(maneuver)
        act.add_maneuver_group(group)
        # the storyboard stops a second after every mover has travelled its track (whatever EgoSpeed is)
        done.add_condition(xosc.EntityTrigger(f"{t.name}_done", 1.0, xosc.ConditionEdge.none,
                                              xosc.TraveledDistanceCondition(round(t.length, 6)), t.name,
                                              triggeringpoint="stop"))
    story = xosc.Story("garage_exp")
    if not act.maneuvergroup:
        group = xosc.ManeuverGroup("ego_group")  # a Story needs an Act, an Act a ManeuverGroup
        group.add_actor("ego")
        act.add_maneuver_group(group)
    story.add_act(act)
    stop = xosc.Trigger("stop")
    if not done.conditions:
        done.add_condition(xosc.ValueTrigger("still", 1.0, xosc.ConditionEdge.none,
                                             xosc.SimulationTimeCondition(0, xosc.Rule.greaterThan), "stop"))
    stop.add_conditiongroup(done)
    cap = xosc.ConditionGroup("stop")  # a file played with EgoSpeed 0 ends too
    cap.add_condition(xosc.ValueTrigger("cap", 0, xosc.ConditionEdge.none,
                                        xosc.SimulationTimeCondition(600, xosc.Rule.greaterThan), "stop"))
    stop.add_conditiongroup(cap)
    board = xosc.StoryBoard(init, stop)
    board.add_story(story)
    description = (f"garage_exp case={info.case} variant={label!r} plan={info.plan} site={info.site} "
                   f"light={info.light} step={step or info.step:g} target={target} "
                   f"ego.speed={info.ego_speed:g} km/h"
                   + "".join(f"; {n}" for n in notes))
    scenario = xosc.Scenario(description, AUTHOR, params, entities, board,
                             xosc.RoadNetwork(roadfile=xodr_name), xosc.Catalog(), osc_minor_version=minor)
    path.parent.mkdir(parents=True, exist_ok=True)
    scenario.write_xml(str(path))
    return path


@dataclass
class ExportConf:
    """The `export` node's schema, beside its check (check_export; core/schema.py registers it by name):
    formats a job writes beside its frames for other tools (garage_exp/exports)."""

    # openscenario/scenario.xosc (ASAM OpenSCENARIO 1.2: entities, initial positions, routes, speeds, triggers)
    # and openscenario/garage.xodr (the plan's driving lanes as ASAM OpenDRIVE); a search writes its hardest
    # trials', a suite each scenario's (docs/openscenario.md)
    openscenario: bool = False
    # "1.2"; or "1.0" for CARLA's ScenarioRunner (its reader takes 1.0 only): the ego marked type=ego_vehicle,
    # CARLA blueprints as vehicle names and pedestrian models, no expressions, no synchronised arrivals (a
    # timed start instead); a reversing ego cannot be said in it and is refused
    openscenario_version: str = "1.2"


VERSIONS = {"1.2": 2, "1.0": 0}
# CARLA 0.9.x blueprints for our bodies and people (ScenarioRunner spawns a Vehicle's `name`, a Pedestrian's
# `model`)
CARLA_VEHICLES = {"car": "vehicle.tesla.model3", "suv": "vehicle.nissan.patrol", "pickup": "vehicle.ford.ranger",
                  "van": "vehicle.volkswagen.t2", "bus": "vehicle.mitsubishi.fusorosa",
                  "truck": "vehicle.carlamotors.carlacola"}
CARLA_WALKERS = {"adult": "walker.pedestrian.0001", "child": "walker.pedestrian.0009"}


def check_export(cfg) -> None:
    """The `export` group: a dry run builds no scenario to write; a version is one we write."""
    if cfg.export.openscenario and cfg.dry_run:
        raise GarageError("a dry run builds no scenario to export; drop dry_run=true or export.openscenario=true",
                          "export.openscenario")
    if str(cfg.export.openscenario_version) not in VERSIONS:
        raise GarageError(f"{cfg.export.openscenario_version!r} is not a version we write (1.2, or 1.0 for CARLA's "
                          "ScenarioRunner)", "export.openscenario_version")


def check_version(version: str, setup) -> None:
    """Refuse, at the job's preflight, a scenario the export's version cannot say (check_tracks): the ego's
    first and last frame of each variant tell whether it reverses."""
    ego = next(e for e in setup.vehicles if e.name == "ego")
    for label in dict.fromkeys(s.label for s in setup.shots if s.replicate == 0):
        shots = [s for s in setup.shots if s.label == label and s.replicate == 0]
        check_tracks(version, label, [Track("ego", ego, shots[0].ego, shots[-1].ego, 1.0)])


def check_tracks(version: str, label: str, moving: list[Track]) -> None:
    """What OpenSCENARIO `version` cannot say, refused in one line: 1.0 for ScenarioRunner has no negative
    speed, so no reversing ego."""
    ego = next((t for t in moving if t.name == "ego"), None)
    if version == "1.0" and ego is not None and ego.velocity < 0:
        raise GarageError(f"CARLA's ScenarioRunner (OpenSCENARIO 1.0) refuses negative speeds: the ego reverses in "
                          f"variant {label!r}; export it as 1.2", "export.openscenario_version")


def write(info: ExportInfo, classified, variants: list[tuple[str, str, float | None, list[Track], list[str]]],
          out: Path) -> list[Path]:
    """`out`/garage.xodr and one .xosc per variant (label, its target, its frames' step, its actors' tracks,
    notes): `scenario.xosc`, `scenario_2.xosc`, ...; the paths."""
    version = info.version
    for label, _, _, moving, _ in variants:
        check_tracks(version, label, moving)
    runs = lane_runs(classified)
    lanes = [ego_lane(runs, next(t for t in moving if t.name == "ego")) for _, _, _, moving, _ in variants]
    # one garage, one rule: the side the ego keeps to (a case's variants drive the same side)
    rule = next((lane.rule for lane in lanes if lane is not None), "RHT")
    lanes = [lane if lane is None or lane.rule == rule else None for lane in lanes]
    xodr_path = write_xodr(classified, out / "garage.xodr", rule, garage_things(
        classified, info.pillar_size, info.ceiling_height, info.wall_thickness))
    paths = [xodr_path]
    for k, ((label, target, step, moving, notes), lane) in enumerate(zip(variants, lanes), start=1):
        name = "scenario.xosc" if k == 1 else f"scenario_{k}.xosc"
        paths.append(write_xosc(info, moving, label, notes, out / name, xodr_path.name, target, step, lane,
                                runs, VERSIONS[version]))
    return paths
