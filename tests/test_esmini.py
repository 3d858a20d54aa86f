"""esmini as the judge of `export.openscenario` (docs/openscenario.md, "Replaying an export"): every shipped case,
exported on two plans and played headless in esmini (../shared/tools/esmini), puts every entity where the job
had it at every frame (within 0.1 m and 5 degrees); esmini reports a collision only where the job's frames have
one; every entity starts inside a lane of the road file (bays and the space beside a lane are lanes too); the ego
stays in the lane the file declares, driving that lane's direction under the road's declared traffic rule (a
reversing ego faces against it). Exports need no rendering, nor the garage around the case: the case is placed
as a job places it (scenario.make_case), not rendered."""

from __future__ import annotations

import itertools
import math

import pytest
from conftest import require
from test_cases import case_setup, library  # noqa: F401  (the cases' placements as a job makes them; the library)

from garage_exp.core.paths import PLANS_DIR

CASES = ["1", "2", "3", "cpnco", "cpra", "crossing", "crouch", "light", "pedestrian", "pullout", "slots", "stepout"]
PLANS = ["research", "garage26x30"]
METRES, DEGREES = 0.1, 5.0


def job_collisions(shots, entities) -> set[frozenset[str]]:
    """The pairs of actors whose footprints overlap in some frame of the job."""
    from garage_exp.scenario.place import footprint, overlap

    extent = {e.name: e.extent for e in entities}
    pairs = set()
    for shot in shots:
        poses = {"ego": shot.ego, **{n: p for n, p in shot.poses.items() if p is not None}}
        for a, b in itertools.combinations(sorted(poses), 2):
            if overlap(footprint(poses[a], extent[a]), footprint(poses[b], extent[b]), tolerance=0.0):
                pairs.add(frozenset((a, b)))
    return pairs


def on_road(road, x: float, y: float) -> bool:
    """Whether a point lies in one of the road's lanes (xodr_read's straight roads)."""
    c, n = math.cos(road.hdg), math.sin(road.hdg)
    s, t = (x - road.x) * c + (y - road.y) * n, -(x - road.x) * n + (y - road.y) * c
    return -1e-6 <= s <= road.length + 1e-6 and road.lane_at(t) is not None


def declared_lanes(xosc) -> dict[str, tuple[str, int]]:
    """Each entity's start as the file declares it: (road id, lane id) of its LanePosition."""
    from garage_exp.openscenario.asam import parse

    out = {}
    for private in parse(xosc).getroot().iterfind("Storyboard/Init/Actions/Private"):
        lane = private.find("PrivateAction/TeleportAction/Position/LanePosition")
        if lane is not None:
            out[private.get("entityRef")] = (lane.get("roadId"), int(lane.get("laneId")))
    return out


@pytest.mark.parametrize("plan", PLANS)
@pytest.mark.parametrize("case", CASES)
def test_esmini_replays_the_export_as_the_job_ran(case, plan, library, tmp_path):
    require("esmini")
    judge(library, tmp_path, f"case={case}", f"plan={plan}")


def judge(library, tmp_path, *overrides: str) -> list:
    """Export the case, play each variant in esmini and hold it to the job's frames (the module's docstring);
    the exported paths."""
    from tools.esmini import play
    from garage_exp.run.openscenario import export
    from garage_exp.openscenario.tracks import frame_clock, tracks, variants_of
    from garage_exp.run.preflight import PreparedJob
    from garage_exp.run.spec import scene_spec
    from garage_exp.openscenario.asam import validate
    from garage_exp.openscenario.xodr_read import read_roads

    cfg, classified, setup = case_setup(library, *overrides)
    job = scene_spec(cfg)  # what the exporter's tracks are handed, as the job hands them
    plan = cfg.plan.name
    paths = export(cfg, tmp_path / "osc", PreparedJob(PLANS_DIR / f"{plan}.yaml", classified, setup=setup))
    roads, _ = read_roads(paths[0])
    assert validate(paths[0]).startswith("opendrive")
    for (label, shots), xosc in zip(variants_of(setup), paths[1:], strict=True):
        where = f"{plan} case={cfg.case.name} [{label}]"
        assert validate(xosc).startswith("OpenSCENARIO")
        moving, _ = tracks(job, setup, shots)
        replay = play(xosc, tmp_path / xosc.stem)
        for shot, t in zip(shots, frame_clock(job, shots, moving)):
            for name, pose in [("ego", shot.ego), *shot.poses.items()]:
                if pose is None:
                    continue
                x, y, h = replay.at(name, t)
                off = math.hypot(x - pose.x, y - pose.y)
                turn = abs((h - pose.yaw + 180.0) % 360.0 - 180.0)
                assert off < METRES and turn < DEGREES, \
                    f"{where} frame {shot.index} t={t:.2f} s: esmini has {name} {off:.2f} m, {turn:.1f} deg off"
        allowed = job_collisions(shots, setup.vehicles)
        assert replay.collided() <= allowed, f"{where}: esmini's collisions {replay.collided()} not the job's"
        for name, rows in replay.samples.items():  # where esmini put it first, on the road file's lanes
            x, y = rows[0].x, rows[0].y
            assert any(on_road(road, x, y) for road in roads.values()), \
                f"{where}: {name} starts off every lane of the road file, at ({x:.2f}, {y:.2f})"
        declared = declared_lanes(xosc)
        ego = next(t for t in moving if t.name == "ego")
        assert "ego" in declared, f"{where}: the file declares no lane for the ego (no LanePosition)"
        lanes = {r.lane for r in replay.samples["ego"]}
        assert lanes == {declared["ego"][1]}, f"{where}: the ego is in lanes {lanes}, declared {declared['ego']}"
        if abs(declared["ego"][1]) == 1:  # an ego in a driving lane (not parked in a bay), standing or driving
            facing = math.pi if ego.velocity < 0 else 0.0  # a reversing ego faces against its lane's direction
            worst = max(abs((r.heading_to_drive - facing + math.pi) % (2 * math.pi) - math.pi)
                        for r in replay.samples["ego"])
            assert worst < math.radians(DEGREES), f"{where}: the ego heads {math.degrees(worst):.0f} deg off its lane"

    return paths


def test_a_1_0_export_is_what_scenario_runner_reads_and_plays_the_same(library, tmp_path):
    """export.openscenario_version=1.0 (CARLA's ScenarioRunner reads 1.0 only): the 1.0 schema, the ego marked
    type=ego_vehicle, CARLA blueprints as vehicle names and pedestrian models, no expressions, no negative speed;
    esmini plays it as the job ran, as the 1.2 file."""
    require("esmini")
    from garage_exp.openscenario.v1_0 import CARLA_VEHICLES, CARLA_WALKERS
    from garage_exp.openscenario.asam import parse, validate

    for case in ("crossing", "cpnco"):
        paths = judge(library, tmp_path / case, f"case={case}", "export.openscenario_version=1.0")
        assert validate(paths[1]) == "OpenSCENARIO_1_0.xsd"
        root = parse(paths[1]).getroot()
        objects = {o.get("name"): o for o in root.iterfind("Entities/ScenarioObject")}
        ego = objects["ego"].find("Vehicle")
        assert ego.find("Properties/Property[@name='type']").get("value") == "ego_vehicle"
        assert all(v.get("name") in CARLA_VEHICLES.values() for v in root.iter("Vehicle"))
        assert {p.get("model") for p in root.iter("Pedestrian")} <= set(CARLA_WALKERS.values())
        text = paths[1].read_text()
        assert "${" not in text and "SynchronizeAction" not in text
        declared = {p.get("name"): p.get("value") for p in root.iter("ParameterDeclaration")}
        speeds = [declared.get(v.get("value")[1:], "") if v.get("value").startswith("$") else v.get("value")
                  for v in root.iter("AbsoluteTargetSpeed")]
        assert speeds and all(float(v) >= 0 for v in speeds), speeds


def test_the_road_file_holds_the_garage_s_pillars_walls_obstacles_and_bays(tmp_path):
    """garage.xodr: the header's bounds are the plan's extent; every pillar is a pole, every perimeter wall a
    barrier, every obstacle cell a building and every bay beside a lane a parkingSpace, with their dimensions."""
    from garage_exp.openscenario.xodr_write import write_xodr
    from garage_exp.plan import classify, load_plan
    from garage_exp.openscenario.asam import parse, validate

    classified = classify(load_plan(PLANS_DIR / "research.yaml"))
    path = write_xodr(classified, tmp_path / "garage.xodr")
    assert validate(path) == "opendrive_17_core.xsd"
    root = parse(path).getroot()
    header = root.find("header")
    width, depth = classified.plan.size
    assert (float(header.get("east")), float(header.get("north"))) == pytest.approx((width, depth))
    objects = root.findall("road/objects/object")
    kinds = {k: [o for o in objects if o.get("type") == k] for k in ("pole", "barrier", "building", "parkingSpace")}
    cells = [c for c in classified.all_cells()]
    assert len(kinds["pole"]) == len(classified.pillars) > 0
    assert all(float(o.get("length")) == float(o.get("width")) == 0.6 for o in kinds["pole"])
    assert len(kinds["building"]) == sum(c.value == -1 for c in cells)
    assert len(kinds["parkingSpace"]) == sum(c.value == 0 and bool(c.lanes) for c in cells) > 0
    assert kinds["barrier"] and sum(float(o.get("length")) for o in kinds["barrier"]) > width + depth


def test_asam_s_checker_bundles_find_nothing_in_the_exports(library, tmp_path):
    """asam-qc-openscenarioxml and asam-qc-opendrive on the files esmini judges: cpnco (1.2: a SynchronizeAction,
    parameters, lane positions, trajectories), crossing as 1.0, and their road files: every checker completes (or
    skips a rule of another version of the standard than the file's) and finds no issue. A broken copy of each
    (an entity that does not exist, two roads of one id) gets its issue: the bundles can fail."""
    require("asam-qc")
    from tools.asam_qc import checkers
    from garage_exp.run.openscenario import export
    from garage_exp.run.preflight import PreparedJob

    files = []
    for case, version in (("cpnco", "1.2"), ("crossing", "1.0")):
        cfg, classified, setup = case_setup(library, f"case={case}", f"export.openscenario_version={version}")
        files += export(cfg, tmp_path / case, PreparedJob(PLANS_DIR / "research.yaml", classified, setup=setup))
    found = {f"{p.parent.name}/{p.name}": checkers(p) for p in files}
    assert all(found.values()), found  # each bundle ran its checkers
    unchecked = {f: [(c["checker"], c["status"], c["summary"]) for c in cs if c["status"] != "completed" and not (
        c["status"] == "skipped" and c["summary"].startswith("Version "))] for f, cs in found.items()}
    assert not any(unchecked.values()), unchecked
    assert not any(c["issues"] for cs in found.values() for c in cs), found
    assert all(c["status"] == "completed" for c in found["cpnco/scenario.xosc"])  # 1.2: every rule applies
    # broken copies beside the originals (the scenario finds its road file there)
    xosc, xodr = tmp_path / "cpnco" / "scenario.xosc", tmp_path / "cpnco" / "garage.xodr"
    ghost = xosc.with_name("ghost.xosc")
    ghost.write_text(xosc.read_text().replace('entityRef="child"', 'entityRef="nobody"', 1))
    twice = xodr.with_name("twice.xodr")
    twice.write_text(xodr.read_text().replace('id="2" junction="-1"', 'id="1" junction="-1"', 1))
    for path, rule in ((ghost, "resolvable_entity_references"), (twice, "valid_schema")):
        said = [line for c in checkers(path) for line in c["issues"]]
        assert any(rule in line for line in said), (path.name, said)


def test_esmini_reports_two_cars_that_overlap_as_a_collision(tmp_path):
    """The judge's collision check can fail: two cars placed 2 m apart along one lane (4.5 m long) overlap, and
    esmini's log says so (Replay.collided); a third, 20 m on, touches neither."""
    require("esmini")
    from scenariogeneration import xosc

    from tools.esmini import play
    from garage_exp.openscenario.lanes import lane_runs
    from garage_exp.openscenario.xodr_write import write_xodr
    from garage_exp.plan import classify, load_plan

    classified = classify(load_plan(PLANS_DIR / "research.yaml"))
    xodr = write_xodr(classified, tmp_path / "garage.xodr")
    road = max(range(len(lane_runs(classified))), key=lambda k: lane_runs(classified)[k].length) + 1
    car = xosc.Vehicle("car", xosc.VehicleCategory.car, xosc.BoundingBox(1.8, 4.5, 1.5, 1.35, 0, 0.75),
                       xosc.Axle(0.5, 0.65, 1.5, 2.7, 0.33), xosc.Axle(0, 0.65, 1.5, 0, 0.33), 30, 3, 8)
    entities, init = xosc.Entities(), xosc.Init()
    for name, s in (("a", 2.0), ("b", 4.0), ("c", 24.0)):
        entities.add_scenario_object(name, car)
        init.add_init_action(name, xosc.TeleportAction(xosc.LanePosition(s, 0, -1, road)))
    stop, condition = xosc.Trigger("stop"), xosc.ConditionGroup("stop")
    condition.add_condition(xosc.ValueTrigger("t", 0, xosc.ConditionEdge.none,
                                              xosc.SimulationTimeCondition(0.5, xosc.Rule.greaterThan), "stop"))
    stop.add_conditiongroup(condition)
    board = xosc.StoryBoard(init, stop)
    board.add_story(xosc.Story("still").add_act(xosc.Act("none").add_maneuver_group(xosc.ManeuverGroup("g"))))
    path = tmp_path / "overlap.xosc"
    xosc.Scenario("two cars in one place", "garage_exp", xosc.ParameterDeclarations(), entities, board,
                  xosc.RoadNetwork(xodr.name), xosc.Catalog()).write_xml(str(path))
    assert play(path, tmp_path / "replay").collided() == {frozenset(("a", "b"))}


def test_a_route_that_turns_a_corner_plays(tmp_path):
    """garage.xodr's junctions: on the research plan's corner, a route from the road into the corner to the road out
    of it is valid in esmini (it logs no route "not valid", no invalid waypoint), and the car follows the turn:
    it passes the route's end, on the road out, in its lane, heading that road's way (right-hand traffic)."""
    require("esmini")
    from scenariogeneration import xosc

    from tools.esmini import play
    from garage_exp.openscenario.lanes import arms, junction_cells, lane_runs
    from garage_exp.openscenario.xodr_write import write_xodr
    from garage_exp.plan import classify, load_plan

    classified = classify(load_plan(PLANS_DIR / "research.yaml"))
    xodr = write_xodr(classified, tmp_path / "garage.xodr")
    runs, cells = lane_runs(classified), junction_cells(classified)
    corner = next(c for c in cells if classified.cell(*c).type == "corner")
    (into, into_end), (out, out_end) = [arms(runs, cells)[corner, d] for d in classified.cell(*corner).lanes]
    ahead = 8.0  # m from the junction on each road
    # right-hand traffic: towards the junction in lane -1 on a road that ends there, in lane 1 on one that starts there
    lane_in, s_in = (-1, runs[into - 1].length - ahead) if into_end == "end" else (1, ahead)
    lane_out, s_out = (-1, ahead) if out_end == "start" else (1, runs[out - 1].length - ahead)
    start, end = xosc.LanePosition(s_in, 0, lane_in, into), xosc.LanePosition(s_out, 0, lane_out, out)
    car = xosc.Vehicle("car", xosc.VehicleCategory.car, xosc.BoundingBox(1.8, 4.5, 1.5, 1.35, 0, 0.75),
                       xosc.Axle(0.5, 0.65, 1.5, 2.7, 0.33), xosc.Axle(0, 0.65, 1.5, 0, 0.33), 30, 3, 8)
    entities = xosc.Entities()
    entities.add_scenario_object("ego", car)
    init = xosc.Init()
    route = xosc.Route("around_the_corner")
    route.add_waypoint(start, xosc.RouteStrategy.shortest)
    route.add_waypoint(end, xosc.RouteStrategy.shortest)
    init.add_init_action("ego", xosc.TeleportAction(start))
    init.add_init_action("ego", xosc.AssignRouteAction(route))
    init.add_init_action("ego", xosc.AbsoluteSpeedAction(4.0, xosc.TransitionDynamics(
        xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0)))
    group = xosc.ManeuverGroup("ego_group")
    group.add_actor("ego")
    act = xosc.Act("drive")
    act.add_maneuver_group(group)
    story = xosc.Story("turn")
    story.add_act(act)
    stop, condition = xosc.Trigger("stop"), xosc.ConditionGroup("stop")
    condition.add_condition(xosc.ValueTrigger("t", 0, xosc.ConditionEdge.none,
                                              xosc.SimulationTimeCondition(12, xosc.Rule.greaterThan), "stop"))
    stop.add_conditiongroup(condition)
    board = xosc.StoryBoard(init, stop)
    board.add_story(story)
    path = tmp_path / "turn.xosc"
    xosc.Scenario("a turn at a corner", "garage_exp", xosc.ParameterDeclarations(), entities, board,
                  xosc.RoadNetwork(xodr.name), xosc.Catalog()).write_xml(str(path))
    replay = play(path, tmp_path / "replay")
    said = (tmp_path / "replay" / "esmini.txt").read_text()
    assert "not valid" not in said and "Invalid waypoint" not in said, said
    road = runs[out - 1]
    centre = -road.width / 4 if lane_out < 0 else road.width / 4
    c, n = math.cos(road.heading), math.sin(road.heading)
    gx, gy = road.start[0] + s_out * c - centre * n, road.start[1] + s_out * n + centre * c
    way = road.heading if lane_out < 0 else road.heading + math.pi
    rows = replay.samples["ego"]
    near = min(rows, key=lambda r: math.hypot(r.x - gx, r.y - gy))
    assert math.hypot(near.x - gx, near.y - gy) < 0.2, (near.x, near.y, gx, gy)
    assert abs((near.h - way + math.pi) % (2 * math.pi) - math.pi) < math.radians(DEGREES)
    x0, y0, x1, y1 = classified.plan.cell_rect(*corner)
    assert any(x0 < r.x < x1 and y0 < r.y < y1 for r in rows)  # through the corner, not around it
