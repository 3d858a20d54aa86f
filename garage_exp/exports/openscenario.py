"""A job's scenario as ASAM OpenSCENARIO 1.2 (`scenario.xosc`) with the garage's driving lanes as ASAM OpenDRIVE
(`garage.xodr`), written with `scenariogeneration`, for the tools test engineers replay scenarios in (esmini,
CARLA's ScenarioRunner, commercial simulators, HIL rigs).

What is written (docs/openscenario.md has the mapping):
- entities: every actor of the variant as a Vehicle (category car/van/bus/truck from its model), a Pedestrian or a
  MiscObject (a box: an obstacle), with its bounding box (our extent; the reference point is the footprint's
  centre on the ground) and Properties saying what garage_exp made it from (role, kind, model, age, height);
- initial positions: TeleportAction to a WorldPosition (x, y in the plan's world frame, which is the .xodr's
  inertial frame; heading in radians, counter-clockwise from +x, as our yaw);
- motion: each moving actor gets a route (AssignRouteAction, its start and end as waypoints) and speed actions:
  the ego drives at `ego.speed` from the start (a negative speed when it reverses, as in `cpra`); an actor moving along with it (`case.motion.along`) starts when
  the ego has travelled to `at` (TraveledDistanceCondition on the ego) at its own speed; any other mover starts
  at the simulation time of its first move (SimulationTimeCondition). Each stops (speed 0) when it has
  travelled its route (TraveledDistanceCondition on itself);
- the storyboard stops at the last frame's time plus one second.

One file per variant of the case (replicate 0): `scenario.xosc` for the first, `scenario_2.xosc`, ... for the
others. A case whose ego stands still sweeps a placement value frame by frame rather than in time; it is written
as the moved actor travelling through its placements at a nominal speed (1.4 m/s for people, `ego.speed` for
others), and the FileHeader's description says so.

The lanes: one OpenDRIVE road per maximal straight run of driveable cells along a row or a column, through the
cells' centres from edge to edge, with one driving lane each side (half the cell's width each). Junctions are
not modelled: roads overlap at corners and junction cells (positions are world positions throughout, so the
scenario does not depend on them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from garage_exp.core.errors import GarageError
from garage_exp.scene.description import Entity, Pose

OSC_MINOR = 2
AUTHOR = "garage_exp"
PREFIX = "garage_exp."  # Properties keys carrying what an entity was made from (read back by the importer)
CATEGORIES = {"car": "car", "suv": "car", "pickup": "van", "van": "van", "bus": "bus", "truck": "truck"}


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


def lane_runs(classified) -> list[tuple[tuple[float, float], float, float, float]]:
    """Maximal straight runs of driveable cells along rows (heading E) and columns (heading N): (start point,
    heading in radians, length, width across)."""
    plan = classified.plan
    m, n = plan.shape
    runs = []

    def connected(a, b, d) -> bool:
        return a.driveable and b.driveable and d in a.lanes

    for i in range(m):
        j = 0
        while j < n:
            cell = classified.cell(i, j)
            if not (cell.driveable and ({"E", "W"} & set(cell.lanes))):
                j += 1
                continue
            k = j
            while k + 1 < n and connected(classified.cell(i, k), classified.cell(i, k + 1), "E"):
                k += 1
            y = plan.cell_center(i, j)[1]
            runs.append(((float(plan.x_edges[j]), y), 0.0, float(plan.x_edges[k + 1] - plan.x_edges[j]),
                         float(plan.R[i])))
            j = k + 1
    for j in range(n):
        i = m - 1
        while i >= 0:  # from the bottom row up: heading N
            cell = classified.cell(i, j)
            if not (cell.driveable and ({"N", "S"} & set(cell.lanes))):
                i -= 1
                continue
            k = i
            while k - 1 >= 0 and connected(classified.cell(k, j), classified.cell(k - 1, j), "N"):
                k -= 1
            x = plan.cell_center(i, j)[0]
            runs.append(((x, float(plan.y_edges[i + 1])), math.pi / 2, float(plan.y_edges[k] - plan.y_edges[i + 1]),
                         float(plan.C[j])))
            i = k - 1
    return runs


def write_xodr(classified, path: Path) -> Path:
    """The plan's driving lanes as OpenDRIVE roads (lane_runs), in the world frame of the plan."""
    from scenariogeneration import xodr

    odr = xodr.OpenDrive(f"garage {classified.plan.name}", revMinor="7")
    for k, (start, heading, length, width) in enumerate(lane_runs(classified), start=1):
        road = xodr.create_road(xodr.Line(length), id=k, left_lanes=1, right_lanes=1, lane_width=width / 2)
        road.planview.set_start_point(start[0], start[1], heading)
        odr.add_road(road)
    odr.adjust_roads_and_lanes()
    path.parent.mkdir(parents=True, exist_ok=True)
    odr.write_xml(str(path))
    return path


def _entity_object(track: Track):
    from scenariogeneration import xosc

    e = track.entity
    length, width, height = e.extent
    box = xosc.BoundingBox(width, length, height, 0.0, 0.0, height / 2)
    props = {"role": e.role, "kind": e.kind or "vehicle", "model": e.model or ""}
    if e.kind == "person":
        props.update(age=e.size_class or "adult", height=f"{height:.3f}")
        # the body's spec name (assets/people.py BodySpec.name: age-gender-build-pose-<height>cm) says what it was
        # made from: the height asked for (a crouching body's box is lower), its pose, build and gender
        parts = (e.model or "").split("-")
        if len(parts) == 5 and parts[4].endswith("cm") and parts[4][:-2].isdigit():
            props.update(gender=parts[1], build=parts[2], pose=parts[3], height=f"{int(parts[4][:-2]) / 100:.2f}")
        obj = xosc.Pedestrian(track.name, 20.0 if e.size_class == "child" else 70.0, xosc.PedestrianCategory.pedestrian,
                              box, model=e.model or "pedestrian")
    elif e.kind == "box":
        obj = xosc.MiscObject(track.name, 100.0, xosc.MiscObjectCategory.obstacle, box)
    else:
        from garage_exp.scene.kinds import kind_of

        body = kind_of(e.model or "")
        props["body"] = body
        props["size"] = e.size_class or ""
        wheel = 0.65 if body in ("car", "suv") else 0.8
        axle = length / 2 - 0.9  # wheels ~0.9 m in from either bumper
        obj = xosc.Vehicle(track.name, getattr(xosc.VehicleCategory, CATEGORIES.get(body, "car")), box,
                           xosc.Axle(0.6, wheel, width * 0.85, axle, wheel / 2),
                           xosc.Axle(0.0, wheel, width * 0.85, -axle, wheel / 2), 30.0, 3.0, 8.0)
    for key, value in props.items():
        obj.add_property(PREFIX + key, str(value))
    return obj


def _position(pose: Pose):
    from scenariogeneration import xosc

    return xosc.WorldPosition(round(pose.x, 6), round(pose.y, 6), 0.0, round(math.radians(pose.yaw % 360.0), 9))


def _speed(value: float, accelerate: float = 0.0):
    """Reach `value` m/s at once, or (accelerate > 0) at the constant acceleration that reaches it after
    `accelerate` metres from standstill (a `rate` of v^2 / 2a m/s^2)."""
    from scenariogeneration import xosc

    if accelerate > 0 and value != 0:
        return xosc.AbsoluteSpeedAction(round(value, 6), xosc.TransitionDynamics(
            xosc.DynamicsShapes.linear, xosc.DynamicsDimension.rate, round(value * value / (2 * accelerate), 6)))
    return xosc.AbsoluteSpeedAction(round(value, 6), xosc.TransitionDynamics(
        xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0))


def write_xosc(cfg, moving: list[Track], label: str, notes: list[str], path: Path, xodr_name: str,
               target: str = "", step: float | None = None) -> Path:
    from scenariogeneration import xosc

    entities = xosc.Entities()
    init = xosc.Init()
    for t in moving:
        entities.add_scenario_object(t.name, _entity_object(t))
        init.add_init_action(t.name, xosc.TeleportAction(_position(t.start)))
        if t.end is not None:
            route = xosc.Route(f"{t.name}_route")
            route.add_waypoint(_position(t.start), xosc.RouteStrategy.shortest)
            route.add_waypoint(_position(t.end), xosc.RouteStrategy.shortest)
            init.add_init_action(t.name, xosc.AssignRouteAction(route))
            if t.trigger == ("time", 0.0):
                init.add_init_action(t.name, _speed(t.velocity, t.accelerate))
    act = xosc.Act("motion", xosc.ValueTrigger("start", 0, xosc.ConditionEdge.none,
                                               xosc.SimulationTimeCondition(0, xosc.Rule.greaterOrEqual)))
    end_time = 0.0
    for t in moving:
        if t.end is None:
            continue
        maneuver = xosc.Maneuver(f"{t.name}_moves")
        if t.trigger != ("time", 0.0):
            kind, value = t.trigger
            go = xosc.Event(f"{t.name}_starts", xosc.Priority.override)
            go.add_action(f"{t.name}_speed", _speed(t.velocity, t.accelerate))
            go.add_trigger(xosc.EntityTrigger(f"ego_travelled_{value:.2f}", 0, xosc.ConditionEdge.rising,
                                              xosc.TraveledDistanceCondition(round(value, 6)), "ego")
                           if kind == "ego_travel" else
                           xosc.ValueTrigger(f"time_{value:.2f}", 0, xosc.ConditionEdge.rising,
                                             xosc.SimulationTimeCondition(round(value, 6), xosc.Rule.greaterOrEqual)))
            maneuver.add_event(go)
        stop = xosc.Event(f"{t.name}_stops", xosc.Priority.override)
        stop.add_action(f"{t.name}_stop", _speed(0.0))
        stop.add_trigger(xosc.EntityTrigger(f"{t.name}_travelled_{t.length:.2f}", 0, xosc.ConditionEdge.rising,
                                            xosc.TraveledDistanceCondition(round(t.length, 6)), t.name))
        maneuver.add_event(stop)
        group = xosc.ManeuverGroup(f"{t.name}_group")
        group.add_actor(t.name)
        group.add_maneuver(maneuver)
        act.add_maneuver_group(group)
        ego_speed = next((e.speed for e in moving if e.name == "ego"), 0.0)
        start = t.trigger[1] if t.trigger[0] == "time" else t.trigger[1] / ego_speed if ego_speed > 0 else 0.0
        end_time = max(end_time, start + (t.length + t.accelerate) / t.speed if t.speed > 0 else start)
    story = xosc.Story("garage_exp")
    if not act.maneuvergroup:
        group = xosc.ManeuverGroup("ego_group")  # a Story needs an Act, an Act a ManeuverGroup
        group.add_actor("ego")
        act.add_maneuver_group(group)
    story.add_act(act)
    stop = xosc.ValueTrigger("end", 0, xosc.ConditionEdge.rising,
                             xosc.SimulationTimeCondition(round(end_time + 1.0, 3), xosc.Rule.greaterThan), "stop")
    board = xosc.StoryBoard(init, stop)
    board.add_story(story)
    case = cfg.case
    description = (f"garage_exp case={case.name} variant={label!r} plan={cfg.plan.name} site={case.site} "
                   f"light={cfg.light.name} step={step or float(case.motion.step):g} target={target} "
                   f"ego.speed={float(cfg.ego.speed):g} km/h"
                   + "".join(f"; {n}" for n in notes))
    scenario = xosc.Scenario(description, AUTHOR, xosc.ParameterDeclarations(), entities, board,
                             xosc.RoadNetwork(roadfile=xodr_name), xosc.Catalog(), osc_minor_version=OSC_MINOR)
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


def check_export(cfg) -> None:
    """The `export` group: a dry run builds no scenario to write."""
    if cfg.export.openscenario and cfg.dry_run:
        raise GarageError("a dry run builds no scenario to export; drop dry_run=true or export.openscenario=true",
                          "export.openscenario")


def write(cfg, classified, variants: list[tuple[str, str, float | None, list[Track], list[str]]], out: Path
          ) -> list[Path]:
    """`out`/garage.xodr and one .xosc per variant (label, its target, its frames' step, its actors' tracks,
    notes): `scenario.xosc`, `scenario_2.xosc`, ...; the paths."""
    xodr_path = write_xodr(classified, out / "garage.xodr")
    paths = [xodr_path]
    for k, (label, target, step, moving, notes) in enumerate(variants, start=1):
        name = "scenario.xosc" if k == 1 else f"scenario_{k}.xosc"
        paths.append(write_xosc(cfg, moving, label, notes, out / name, xodr_path.name, target, step))
    return paths
