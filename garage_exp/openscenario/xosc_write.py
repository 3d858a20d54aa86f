"""A job's scenario as ASAM OpenSCENARIO 1.2 (`scenario.xosc`, beside the garage's driving lanes as ASAM OpenDRIVE
in `garage.xodr`: xodr_write.py), written with `scenariogeneration`, for the tools test engineers replay scenarios
in (esmini, CARLA's ScenarioRunner, commercial simulators, HIL rigs).

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
it, and turns) link the roads that end at its edges (lanes.py, xodr_write.py).
"""

from __future__ import annotations

import math
from pathlib import Path

from garage_exp.openscenario.lanes import EgoLane, lane_of
from garage_exp.openscenario.model import ExportInfo, Track, axle_offset, reference
from garage_exp.openscenario import v1_0
from garage_exp.scene.description import Entity, Pose

OSC_MINOR = 2
VERSIONS = {"1.2": 2, "1.0": 0}  # export.openscenario_version -> the minor version written
AUTHOR = "garage_exp"
PREFIX = "garage_exp."  # Properties keys carrying what an entity was made from (read back by the importer)
CATEGORIES = {"car": "car", "suv": "car", "pickup": "van", "van": "van", "bus": "bus", "truck": "truck"}


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
        model = v1_0.walker(e.size_class) if carla else e.model or "pedestrian"
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
        name = v1_0.vehicle(body) if carla else track.name
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
