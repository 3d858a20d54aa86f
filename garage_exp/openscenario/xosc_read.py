"""An OpenSCENARIO file read into plain data: its parameters (with `--param` overrides and `${...}`
expressions), its entities (inline or from its catalogs), where each starts (world, lane, road and relative
positions, resolved on its OpenDRIVE's straight roads), its speeds, routes and trajectories, and what starts them.

Whatever it cannot represent is noted in `Read.left_out`, one line per element; a position on a road it cannot
place (no such road, a curved one, no road file) is a GarageError naming the file and the element.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from garage_exp.core.errors import GarageError
from garage_exp.openscenario.xodr_read import read_roads
from garage_exp.openscenario.xosc_params import Values


@dataclass
class Thing:
    """An entity: its OpenSCENARIO type (Vehicle | Pedestrian | MiscObject), category, size, properties."""

    name: str
    type: str
    category: str
    extent: tuple[float, float, float]  # length, width, height (m)
    centre_x: float = 0.0  # the bounding box's centre ahead of the entity's reference point
    properties: dict[str, str] = field(default_factory=dict)
    element: object = None


@dataclass
class Move:
    """A speed an entity takes: m/s, the acceleration towards it (0: a step), and what starts it."""

    speed: float
    rate: float = 0.0  # m/s^2 (0: at once)
    trigger: tuple = ("init", 0.0)  # ("init", 0) | ("time", s) | ("travel", m travelled by `by`) |
    # ("headway", s, of whom, freespace): `by` is that many seconds from the other entity
    by: str = ""  # the entity whose travel starts it
    meet: tuple | None = None  # a SynchronizeAction: (master, its position, own target (x, y), steady distance)


@dataclass
class Read:
    path: Path
    description: str
    things: dict[str, Thing]
    start: dict[str, tuple[float, float, float]]  # name -> x, y, heading (radians)
    moves: dict[str, list[Move]]
    routes: dict[str, list[tuple[float, float]]]  # name -> waypoints (a route or a trajectory's vertices)
    left_out: list[str]
    tree: object = None


# ---- the file --------------------------------------------------------------------------------------------------

ENTITY_TYPES = ("Vehicle", "Pedestrian", "MiscObject")


class Reader:
    def __init__(self, path: Path, tree, params: dict[str, str]):
        self.path, self.tree, self.root = path, tree, tree.getroot()
        self.values = Values(path, tree)
        block = self.root.find("ParameterDeclarations")
        # a --param the file does not declare is a typo, not a new parameter (Values.declare keeps assignments
        # it has no declaration for, as a catalog reference may make): refused before it is put in scope
        declared = {d.get("name") for d in (block.findall("ParameterDeclaration") if block is not None else [])}
        unknown = sorted(set(params) - declared)
        if unknown:
            raise GarageError(f"--param {unknown[0]}: the file declares no such parameter "
                              f"(it declares {', '.join(sorted(declared)) or 'none'})", str(path))
        self.values.scopes = [self.values.declare(block, dict(params))]
        self.left_out: list[str] = []
        self.start: dict[str, tuple[float, float, float]] = {}
        self.things: dict[str, Thing] = {}
        self.roads, self.refused = self._roads()

    def where(self, element) -> str:
        return self.values.where(element)

    def leave(self, element, why: str) -> None:
        self.left_out.append(f"left out {self.tree.getpath(element)} <{element.tag}"
                             + (f" name={element.get('name')!r}" if element.get("name") else "") + f">: {why}")

    def _roads(self):
        logic = self.root.find("RoadNetwork/LogicFile")
        if logic is None or not logic.get("filepath"):
            return {}, {}
        xodr = (self.path.parent / self.values.get(logic, "filepath")).resolve()
        if not xodr.is_file():
            return {}, {"*": f"its road file {xodr} is not there"}
        return read_roads(xodr)

    # catalogs
    def catalog_entry(self, ref):
        """The catalog element a CatalogReference names, with its parameters in scope (pushed: pop after)."""
        name, entry = self.values.get(ref, "catalogName"), self.values.get(ref, "entryName")
        folders = [self.values.get(d, "path") for d in self.root.findall("CatalogLocations/*/Directory")]
        from garage_exp.openscenario.asam import parse

        for folder in folders:
            for file in sorted((self.path.parent / folder).glob("*.xosc")):
                catalog = parse(file).getroot().find("Catalog")
                if catalog is None or catalog.get("name") != name:
                    continue
                for element in catalog:
                    if element.get("name") == entry:
                        assigned = {a.get("parameterRef"): self.values.get(a, "value")
                                    for a in ref.findall("ParameterAssignments/ParameterAssignment")}
                        self.values.scopes.append(self.values.declare(element.find("ParameterDeclarations"),
                                                                      assigned))
                        return element
        raise GarageError(f"no entry {entry!r} in a catalog {name!r} under {', '.join(folders) or 'no folder'}",
                          self.where(ref))

    def entities(self) -> None:
        for obj in self.root.findall("Entities/ScenarioObject"):
            name = obj.get("name")
            for controller in obj.findall("ObjectController"):  # a driver model: a case's actors follow its motion
                self.leave(controller, f"{name}'s controller ({_controller_name(controller)}): a case's actors "
                           "move as its motion says, with no driver model")
            element, pushed = next((c for c in obj if c.tag in ENTITY_TYPES), None), False
            ref = obj.find("CatalogReference")
            if element is None and ref is not None:
                element, pushed = self.catalog_entry(ref), True
            if element is None or element.tag not in ENTITY_TYPES:
                self.leave(obj, "an entity of a kind we have no actor for")
                if pushed:
                    self.values.scopes.pop()
                continue
            box = element.find("BoundingBox")
            dims, centre = box.find("Dimensions"), box.find("Center")
            category = element.get("vehicleCategory") or element.get("pedestrianCategory") \
                or element.get("miscObjectCategory") or ""
            props = {p.get("name"): p.get("value") for p in element.findall("Properties/Property")}
            self.things[name] = Thing(name, element.tag, category,
                                      (self.values.num(dims, "length"), self.values.num(dims, "width"),
                                       self.values.num(dims, "height")),
                                      self.values.num(centre, "x", 0.0), props, obj)
            if pushed:
                self.values.scopes.pop()

    # positions
    def position(self, pos) -> tuple[float, float, float]:
        """A Position element as world x, y and heading (radians) of the entity's reference point."""
        kind = next(iter(pos), None)
        if kind is None:
            raise GarageError("an empty Position", self.where(pos))
        v = self.values
        if kind.tag == "WorldPosition":
            return v.num(kind, "x"), v.num(kind, "y"), v.num(kind, "h", 0.0)
        if kind.tag in ("LanePosition", "RoadPosition"):
            road = self.road(kind)
            t = v.num(kind, "t", 0.0) if kind.tag == "RoadPosition" else \
                road.lane_centre(int(v.num(kind, "laneId"))) + v.num(kind, "offset", 0.0)
            x, y = road.point(v.num(kind, "s"), t)
            lane = int(v.num(kind, "laneId", -1)) if kind.tag == "LanePosition" else -1
            h = road.hdg + (0.0 if lane < 0 else math.pi)  # driving direction: right lanes along s
            return x, y, self.orientation(kind, h)
        if kind.tag == "RelativeLanePosition":
            ref = v.get(kind, "entityRef")
            if ref not in self.start:
                raise GarageError(f"relative to {ref!r}, placed after it or not at all", self.where(kind))
            if v.num(kind, "dLane", 0.0):
                raise GarageError("a lane change (dLane) we cannot place", self.where(kind))
            x0, y0, h0 = self.start[ref]
            road, s, t = self.on_road(x0, y0, kind)
            lane = road.lane_at(t)  # `offset` is from the centre of the reference's lane, not from the reference
            x, y = road.point(s + v.num(kind, "ds", 0.0), road.lane_centre(lane) + v.num(kind, "offset", 0.0))
            return x, y, self.orientation(kind, h0)
        if kind.tag == "RelativeWorldPosition":
            ref = v.get(kind, "entityRef")
            if ref not in self.start:
                raise GarageError(f"relative to {ref!r}, placed after it or not at all", self.where(kind))
            x0, y0, h0 = self.start[ref]
            return x0 + v.num(kind, "dx", 0.0), y0 + v.num(kind, "dy", 0.0), self.orientation(kind, h0)
        if kind.tag == "TrajectoryPosition":  # s metres along a polyline trajectory
            pts = self.trajectory(kind.find("TrajectoryRef"))
            x, y = along_polyline(pts, v.num(kind, "s"))
            (x0, y0), (x1, y1) = pts[0], pts[-1]
            return x, y, math.atan2(y1 - y0, x1 - x0)
        raise GarageError(f"a {kind.tag} we cannot place (world, lane, road, relative or trajectory positions)",
                          self.where(kind))

    def trajectory(self, holder) -> list[tuple[float, float]]:
        """The vertices (x, y) of the polyline trajectory an element holds (inline, or from a catalog)."""
        return self.timed_trajectory(holder)[0]

    def timed_trajectory(self, holder) -> tuple[list[tuple[float, float]], list[float] | None]:
        """The vertices (x, y) of the polyline trajectory an element holds (inline, or from a catalog), and their
        times (None unless every vertex has one)."""
        ref = holder.find("CatalogReference") if holder is not None else None
        element = self.catalog_entry(ref) if ref is not None else (
            holder.find("Trajectory") if holder is not None else None)
        try:
            vertices = element.findall("Shape/Polyline/Vertex") if element is not None else []
            if not vertices:
                raise GarageError("a trajectory other than a polyline (clothoid, NURBS) we cannot place",
                                  self.where(holder))
            times = [self.values.get(vx, "time") for vx in vertices]
            return ([self.position(vx.find("Position"))[:2] for vx in vertices],
                    None if None in times else [self.values.num(vx, "time") for vx in vertices])
        finally:
            if ref is not None:
                self.values.scopes.pop()

    def on_road(self, x: float, y: float, element):
        """The straight road under (x, y), and its s and t there."""
        for road in self.roads.values():
            c, n = math.cos(road.hdg), math.sin(road.hdg)
            s, t = (x - road.x) * c + (y - road.y) * n, -(x - road.x) * n + (y - road.y) * c
            if -1e-6 <= s <= road.length + 1e-6 and road.lane_at(t) is not None:
                return road, s, t
        raise GarageError("a lane position relative to an entity on no road the plan can place", self.where(element))

    def orientation(self, kind, base: float) -> float:
        o = kind.find("Orientation")
        if o is None:
            return base
        h = self.values.num(o, "h", 0.0)
        return h if o.get("type") == "absolute" else base + h

    def road(self, kind):
        rid = str(self.values.get(kind, "roadId"))
        if rid in self.roads:
            return self.roads[rid]
        why = self.refused.get(rid) or self.refused.get("*") or "no such road in the road file"
        raise GarageError(f"needs road {rid}, which the plan cannot place: {why}", self.where(kind))

    def centre(self, name: str, x: float, y: float, h: float) -> tuple[float, float, float]:
        """The entity's bounding-box centre (our actors' reference) from its reference point."""
        cx = self.things[name].centre_x if name in self.things else 0.0
        return x + cx * math.cos(h), y + cx * math.sin(h), h


def _controller_name(controller) -> str:
    ref = controller.find("CatalogReference")
    if ref is not None:
        return f"{ref.get('catalogName')}/{ref.get('entryName')}"
    inline = controller.find("Controller")
    return inline.get("name", "inline") if inline is not None else "inline"


def along_polyline(pts: list[tuple[float, float]], s: float) -> tuple[float, float]:
    """The point s metres along a polyline (beyond its ends: on its first or last piece, extended)."""
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        piece = math.hypot(x1 - x0, y1 - y0)
        if s <= piece or (x1, y1) == pts[-1]:
            k = s / (piece or 1.0)
            return x0 + k * (x1 - x0), y0 + k * (y1 - y0)
        s -= piece
    return pts[0]


def read(path: Path, params: dict[str, str] | None = None) -> Read:
    """The file, schema-checked, as plain data (module docstring)."""
    from garage_exp.openscenario.asam import parse, validate

    tree = parse(path)
    validate(path, tree)
    root = tree.getroot()
    if root.find("Storyboard") is None:
        what = "a parameter variation (ParameterValueDistribution)" if root.find("ParameterValueDistribution") \
            is not None else "a catalog" if root.find("Catalog") is not None else "no scenario"
        raise GarageError(f"{what}, not a scenario with a Storyboard (give its ScenarioFile, with --param for "
                          "the values)", str(path))
    r = Reader(path, tree, params or {})
    r.entities()
    moves: dict[str, list[Move]] = {n: [] for n in r.things}
    routes: dict[str, list[tuple[float, float]]] = {}
    for private in root.findall("Storyboard/Init/Actions/Private"):
        name = private.get("entityRef")
        for action in private.findall("PrivateAction"):
            _private_action(r, name, action, (("init", 0.0), ""), moves, routes)
    for global_action in root.findall("Storyboard/Init/Actions/GlobalAction"):
        r.leave(global_action, "global actions (environment, traffic) are our light, palette and occupancy")
    for event in root.iter("Event"):
        trigger = _trigger(r, event.find("StartTrigger"))
        actors = [e.get("entityRef") for e in event.getparent().getparent().findall("Actors/EntityRef")]
        for action in event.findall("Action"):
            private = action.find("PrivateAction")
            if private is None or not actors:
                r.leave(action, "not an action of an actor (global or user-defined)")
                continue
            for name in actors:
                _private_action(r, name, private, trigger, moves, routes)
    for group in root.iter("ManeuverGroup"):
        if group.find("CatalogReference") is not None:
            r.leave(group.find("CatalogReference"), "a maneuver from a catalog (logging, variables)")
    for extra in ("VariableDeclarations", "MonitorDeclarations"):
        if root.find(extra) is not None:
            r.leave(root.find(extra), "variables and monitors have no counterpart in a case")
    if root.find("Storyboard/StopTrigger") is not None:
        r.leave(root.find("Storyboard/StopTrigger"), "a case ends with its motion")
    starts = {n: r.centre(n, *p) for n, p in r.start.items()}
    routes = {n: [r.centre(n, x, y, starts[n][2])[:2] for x, y in pts] for n, pts in routes.items() if n in starts}
    header = root.find("FileHeader")
    return Read(path, header.get("description", "") if header is not None else "", r.things, starts, moves, routes,
                r.left_out, tree)


def _private_action(r: Reader, name: str, action, trigger, moves, routes) -> None:
    v = r.values
    first = next(iter(action), None)
    if name not in r.things:
        r.leave(action, f"an action of {name!r}, an entity left out")
        return
    tele = action.find("TeleportAction/Position")
    speed = action.find("LongitudinalAction/SpeedAction")
    route = action.find("RoutingAction/AssignRouteAction/Route")
    trajectory = action.find("RoutingAction/FollowTrajectoryAction")
    sync = action.find("SynchronizeAction")
    if tele is not None and trigger[0][0] == "init":
        r.start[name] = r.position(tele)
    elif speed is not None and speed.find("SpeedActionTarget/AbsoluteTargetSpeed") is not None:
        dyn = speed.find("SpeedActionDynamics")
        rate = 0.0
        if dyn is not None and dyn.get("dynamicsShape") != "step" and v.num(dyn, "value", 0.0) > 0:
            if dyn.get("dynamicsDimension") == "rate":
                rate = v.num(dyn, "value")
            else:
                r.leave(dyn, f"a speed change over {dyn.get('dynamicsDimension')}: taken as a step")
        moves[name].append(Move(v.num(speed.find("SpeedActionTarget/AbsoluteTargetSpeed"), "value"), rate, *trigger))
    elif route is not None:
        routes[name] = [r.position(w.find("Position"))[:2] for w in route.findall("Waypoint")]
    elif trajectory is not None:
        holder = trajectory.find("TrajectoryRef")
        try:
            pts, times = r.timed_trajectory(holder if holder is not None else trajectory)
        except GarageError:
            r.leave(trajectory, "a trajectory other than a polyline (clothoid, NURBS)")
            return
        routes[name] = pts
        if name not in r.start:  # a trajectory in the Init places its entity at its first vertex, heading along it
            (x0, y0), (x1, y1) = pts[0], pts[1]
            r.start[name] = (x0, y0, math.atan2(y1 - y0, x1 - x0))
        timed = _timed_move(r, trajectory, pts, times, trigger)
        if timed is not None:
            moves[name].append(timed)
    elif sync is not None:
        _synchronize(r, name, sync, trigger, moves)
    else:
        r.leave(action, f"{first.tag if first is not None else 'an empty action'} has no counterpart in a case")


def _timed_move(r: Reader, action, pts, times, trigger) -> Move | None:
    """A FollowTrajectoryAction whose polyline's vertices have times (TimeReference Timing) moves its entity on
    its own (no SpeedAction): at the polyline's length over its duration, from its first vertex's time (after
    the trigger, or on the simulation's clock with domainAbsoluteRelative absolute)."""
    timing = action.find("TimeReference/Timing")
    if timing is None or times is None or len(pts) < 2:
        return None
    v = r.values
    scale, shift = v.num(timing, "scale", 1.0), v.num(timing, "offset", 0.0)
    duration = (times[-1] - times[0]) * scale
    legs = [math.hypot(x1 - x0, y1 - y0) for (x0, y0), (x1, y1) in zip(pts, pts[1:])]
    if duration <= 0 or sum(legs) <= 0:
        r.leave(timing, "a timed trajectory of no duration or no length: left standing")
        return None
    speed = sum(legs) / duration
    paces = [legs[k] / ((times[k + 1] - times[k]) * scale) for k in range(len(legs)) if times[k + 1] > times[k]]
    if paces and max(paces) - min(paces) > 0.05 * speed:
        r.leave(timing, f"its legs' speeds ({min(paces):.2f}-{max(paces):.2f} m/s): walked at their mean, "
                f"{speed:.2f} m/s")
    begin = times[0] * scale + shift  # when it leaves its first vertex
    (kind, value, *more), by = trigger
    if kind == "headway":
        if begin:
            r.leave(timing, f"its first vertex {begin:g} s after a time-headway trigger: taken as 0 s")
        return Move(speed, 0.0, trigger[0], by)
    if timing.get("domainAbsoluteRelative") == "absolute":
        if kind == "travel":
            r.leave(timing, "vertex times on the simulation's clock after a travelled-distance trigger: taken as "
                    "starting with the trigger")
        else:
            kind, value = "time", max(value, begin)
    elif kind in ("init", "time"):
        kind, value = ("time", value + begin) if value + begin > 0 else (kind, value)
    elif begin:
        r.leave(timing, f"its first vertex {begin:g} s after a travelled-distance trigger: taken as 0 s")
    return Move(speed, 0.0, (kind, value), by)


def _synchronize(r: Reader, name: str, sync, trigger, moves) -> None:
    """A SynchronizeAction (arrive at a point as the master entity reaches its own): our `meet`."""
    v = r.values
    master = v.get(sync, "masterEntityRef")
    final = sync.find("FinalSpeed/AbsoluteSpeed")
    if final is None:
        r.leave(sync, "a synchronisation without an absolute final speed")
        return
    master_at = r.position(sync.find("TargetPositionMaster"))
    target = r.position(sync.find("TargetPosition"))[:2]
    steady = final.find("TargetDistanceSteadyState")
    moves[name].append(Move(v.num(final, "value"), 0.0, *trigger, meet=(
        master, master_at[:2], target, v.num(steady, "distance") if steady is not None else None)))


def _trigger(r: Reader, start) -> tuple[tuple, str]:
    """An event's start trigger as (kind, value, ...) and the entity it watches (Move.trigger)."""
    if start is None:
        return ("time", 0.0), ""
    conditions = start.findall("ConditionGroup/Condition")
    for c in conditions:
        travelled = c.find("ByEntityCondition/EntityCondition/TraveledDistanceCondition")
        ent = c.find("ByEntityCondition/TriggeringEntities/EntityRef")
        if travelled is not None and ent is not None:
            return ("travel", r.values.num(travelled, "value")), ent.get("entityRef")
        time = c.find("ByValueCondition/SimulationTimeCondition")
        if time is not None:
            return ("time", r.values.num(time, "value")), ""
        headway = c.find("ByEntityCondition/EntityCondition/TimeHeadwayCondition")
        if headway is not None and ent is not None and headway.get("rule") in ("lessThan", "lessOrEqual"):
            # (ALKS 4.2.3's crossing pedestrian: it sets off when the ego is 3.6 s from it)
            return ("headway", r.values.num(headway, "value"), r.values.get(headway, "entityRef"),
                    r.values.get(headway, "freespace", "false") == "true"), ent.get("entityRef")
    if conditions:
        r.leave(conditions[0], "a start condition other than time, travelled distance or time headway: taken as "
                "the start")
    return ("time", 0.0), ""
