"""OpenSCENARIO out and in (docs/openscenario.md): a job's scenario written as .xosc + .xodr that the ASAM schemas
accept and that read back, a case imported from an .xosc, the cpnco round trip within 5 cm, and the importer's
bad input (one line naming the file and element, exit 2, nothing written)."""

from __future__ import annotations

import math

import pytest
from test_cases import case_setup, library  # noqa: F401  (the cases' placements as a job makes them; the library)
from xosc_files import ROAD as FOREIGN_XODR  # a straight road of two 3.5 m lanes

from garage_exp.core.paths import PLANS_DIR


@pytest.fixture(scope="module")
def placed(library):
    """The module's placements, each built once: (cfg, classified plan, setup) by the overrides (the round trip
    at three speeds, the other-speed imports and the reversing ego build the same cases at the same speeds)."""
    made = {}

    def get(*overrides: str):
        if overrides not in made:
            made[overrides] = case_setup(library, *overrides)
        return made[overrides]

    return get


@pytest.fixture(scope="module")
def exported(placed, tmp_path_factory):
    """Each (case, ego speed)'s export on the research plan, written once: (cfg, classified, setup, paths)."""
    from garage_exp.run.openscenario import export
    from garage_exp.run.preflight import PreparedJob

    made = {}

    def get(case: str, speed: float):
        if (case, speed) not in made:
            cfg, classified, setup = placed(f"case={case}", f"ego.speed={speed}")
            out = tmp_path_factory.mktemp(f"osc_{case}_{speed}") / "openscenario"
            paths = export(cfg, out, PreparedJob(PLANS_DIR / "research.yaml", classified, setup=setup))
            made[case, speed] = cfg, classified, setup, paths
        return made[case, speed]

    return get


@pytest.fixture(scope="module")
def cpnco(exported):
    """case=cpnco at its default speed (10 km/h) exported."""
    return exported("cpnco", 10)


def test_cpnco_exports_validate_against_the_asam_schemas_and_read_back(cpnco):
    from scenariogeneration import xosc

    from garage_exp.openscenario.lanes import lane_runs, turns
    from garage_exp.openscenario.xodr_read import read_roads

    from garage_exp.openscenario.asam import validate

    cfg, classified, setup, paths = cpnco
    assert [p.name for p in paths] == ["garage.xodr", "scenario.xosc"]
    assert validate(paths[0]) == "opendrive_17_core.xsd" and validate(paths[1]) == "OpenSCENARIO_1_2.xsd"
    scenario = xosc.ParseOpenScenario(str(paths[1]))  # scenariogeneration's own reader takes it back
    assert {o.name for o in scenario.entities.scenario_objects} == {"ego", "child", "car_large", "car_small"}
    # the research plan's lanes: the ring's four sides, the two ramps' columns, and the junctions' straight connecting
    # roads; the junctions' turns are arcs, which the importer does not place on (each refused with its reason)
    roads, refused = read_roads(paths[0])
    assert len(roads) == len(lane_runs(classified)) >= 4
    assert len(refused) == len(turns(classified)) > 0 and all("arc" in why for why in refused.values())
    for road in roads.values():  # each road's centre line runs over driveable cells
        for k in range(1, 10):
            cell = classified.plan.cell_at(*road.point(road.length * k / 10, 0.0))
            assert cell is not None and classified.cell(*cell).driveable
    text = paths[1].read_text()
    for needle in ("TraveledDistanceCondition", "AssignRouteAction", "AbsoluteTargetSpeed value=\"$EgoSpeed\"",
                   'ParameterDeclaration name="EgoSpeed" parameterType="double" value="2.777778"',
                   "FollowTrajectoryAction", "pedestrianCategory=\"pedestrian\"", "SimulationTimeCondition"):
        assert needle in text


def assert_same_placements(original: list, again: list) -> None:
    """Frame for frame, every actor within 5 cm and half a degree of where it stood."""
    assert len(again) == len(original)
    worst = 0.0
    for a, b in zip(original, again):
        worst = max(worst, math.hypot(a.ego.x - b.ego.x, a.ego.y - b.ego.y))
        for name, pose in a.poses.items():
            if pose is None:
                continue
            other = b.poses[name]
            worst = max(worst, math.hypot(pose.x - other.x, pose.y - other.y))
            assert abs(((pose.yaw - other.yaw) + 180) % 360 - 180) < 0.5
    assert worst < 0.05, f"worst {worst:.3f} m"


def test_the_cpnco_export_imports_back_to_the_same_placements(cpnco, library, tmp_path):
    """Round trip: the imported case builds every frame's poses within 5 cm of the original's."""
    from garage_exp.openscenario.xosc_import import main

    cfg, classified, setup, paths = cpnco
    out = tmp_path / "conf" / "case" / "cpnco_rt.yaml"
    assert main([str(paths[1]), "-o", str(out), "--name", "cpnco_rt"]) == 0
    _, _, again = case_setup(library, "case=cpnco_rt", f"hydra.searchpath=[file://{tmp_path / 'conf'}]")
    assert_same_placements(setup.shots, again.shots)


@pytest.mark.parametrize("speed", [5, 20])
def test_the_cpnco_export_imports_back_at_other_ego_speeds(cpnco, placed, library, tmp_path, speed):
    """The child's timed arrival is a SynchronizeAction with the ego, not a trigger fixed for the exported speed:
    imported back and run at 5 or 20 km/h, the case builds the same frames as the original at that speed (with a
    trigger the child set off 10 frames early at 5 km/h, and was 2.5 m short of the ego's path at 20)."""
    from garage_exp.openscenario.xosc_import import main

    cfg, classified, setup, paths = cpnco
    assert "SynchronizeAction" in paths[1].read_text()
    out = tmp_path / "conf" / "case" / "cpnco_v.yaml"
    assert main([str(paths[1]), "-o", str(out), "--name", "cpnco_v"]) == 0
    _, _, original = placed("case=cpnco", f"ego.speed={speed}")
    _, _, again = case_setup(library, "case=cpnco_v", f"ego.speed={speed}",
                             f"hydra.searchpath=[file://{tmp_path / 'conf'}]")
    assert_same_placements(original.shots, again.shots)


def test_a_reversing_ego_and_a_synchronised_walker_import_back(exported, library, tmp_path):
    """cpra's walking variant at 4 km/h (the ego reverses: a negative speed; the adult's walk is timed to meet
    it) exported and imported again: the same placements, frame for frame."""
    from garage_exp.openscenario.xosc_import import main

    cfg, classified, setup, paths = exported("cpra", 4)
    walking = paths[7]  # the seventh variant: adult walking 50 %
    assert "adult walking 50 %" in walking.read_text() and 'name="EgoSpeed" parameterType="double" value="-1.111111"' in walking.read_text()
    out = tmp_path / "conf" / "case" / "cpra_rt.yaml"
    assert main([str(walking), "-o", str(out), "--name", "cpra_rt"]) == 0
    _, _, again = case_setup(library, "case=cpra_rt", "ego.speed=4", f"hydra.searchpath=[file://{tmp_path / 'conf'}]")
    assert_same_placements([s for s in setup.shots if s.label == "adult walking 50 %"], again.shots)


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_a_stepout_job_with_export_openscenario_writes_both_files(tmp_path, mlflow_uri):
    """A job (three frames) writes openscenario/scenario.xosc and garage.xodr beside its frames."""
    from conftest import require, run_app

    from garage_exp.openscenario.asam import validate

    require("vulkan", "vehicles", "models")
    out = tmp_path / "run"
    result = run_app(["case=stepout", "export.openscenario=true", "case.motion.step=8.5", "camera.width=320",
                      "camera.height=240", "renderer.save_frames=none", f"hydra.run.dir={out}",
                      f"tracking.uri={mlflow_uri}"], tmp_path)
    assert result.returncode == 0, result.stderr
    assert (out / "frames.csv").is_file()
    assert validate(out / "openscenario" / "scenario.xosc").startswith("OpenSCENARIO_1_2")
    assert validate(out / "openscenario" / "garage.xodr").startswith("opendrive")


BAD_XOSC = {
    "not_xml.xosc": ("<OpenSCENARIO><FileHeader", "not XML"),
    "schema.xosc": ('<?xml version="1.0"?><OpenSCENARIO><FileHeader revMajor="1" revMinor="2" date="2026-01-01T00:00:00"'
                    ' description="x" author="y"/><Bogus/></OpenSCENARIO>', "fails the schema OpenSCENARIO_1_2.xsd"),
}


@pytest.mark.parametrize("name", sorted(BAD_XOSC))
def test_a_bad_xosc_is_one_line_exit_2_and_nothing_written(name, tmp_path, capsys):
    from garage_exp.openscenario.xosc_import import main

    text, says = BAD_XOSC[name]
    path = tmp_path / name
    path.write_text(text)
    out = tmp_path / "case" / "x.yaml"
    assert main([str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and says in err
    assert not out.exists() and not out.parent.exists()


def test_a_road_the_plan_cannot_place_is_refused(cpnco, tmp_path, capsys):
    """A lane position on a road the road file lacks, and an actor moved outside the plan: one line naming the
    element, exit 2."""
    from garage_exp.openscenario.xosc_import import main

    from lxml import etree

    def changed(edit) -> str:
        tree = etree.parse(str(cpnco[3][1]))
        edit(tree)
        return etree.tostring(tree, encoding="unicode")

    def on_road_99(tree):  # the child's start as a lane position on a road the road file lacks
        start = tree.find("Storyboard/Init/Actions/Private[@entityRef='child']/PrivateAction/TeleportAction"
                          "/Position/*")
        start.getparent().replace(start, etree.Element("LanePosition", roadId="99", laneId="-1", s="3",
                                                       offset="0"))

    def far_away(tree):  # the large car 300 m east, outside the plan
        start = tree.find("Storyboard/Init/Actions/Private[@entityRef='car_large']/PrivateAction/TeleportAction"
                          "/Position/*")
        start.getparent().replace(start, etree.Element("WorldPosition", x="330", y="40", h="0"))

    lane, far = changed(on_road_99), changed(far_away)
    for name, bad, says in (("lane.xosc", lane, "needs road 99"), ("far.xosc", far, "needs a road the plan")):
        path = tmp_path / name
        path.write_text(bad)
        (tmp_path / "garage.xodr").write_text(cpnco[3][0].read_text())
        out = tmp_path / "case" / "x.yaml"
        assert main([str(path), "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err and says in err, err
        assert "ScenarioObject" in err or "Position" in err
        assert not out.exists()


def test_python_m_garage_exp_scenario_import_runs(cpnco, tmp_path):
    """`python -m garage_exp.scenario.import` as -m runs it (runpy, in this process: conftest.run_module; the
    command in its own process, signals and bad input: test_command_exits.py)."""
    from conftest import run_module

    result = run_module("garage_exp.scenario.import", [str(cpnco[3][1]), "--name", "rt"], tmp_path)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "case" / "rt.yaml").is_file() and "left out" in result.stdout



FOREIGN_XOSC = """<?xml version="1.0"?>
<OpenSCENARIO><FileHeader revMajor="1" revMinor="2" date="2026-01-01T00:00:00" description="a crossing" author="t"/>
<ParameterDeclarations>
  <ParameterDeclaration name="EgoS" parameterType="double" value="20"/>
  <ParameterDeclaration name="Ahead" parameterType="double" value="${$EgoS + 12}"/>
</ParameterDeclarations>
<CatalogLocations/><RoadNetwork><LogicFile filepath="road.xodr"/></RoadNetwork>
<Entities>
  <ScenarioObject name="Hero"><Vehicle name="car" vehicleCategory="car"><BoundingBox><Center x="1.4" y="0" z="0.7"/>
    <Dimensions width="1.8" length="4.4" height="1.4"/></BoundingBox><Performance maxSpeed="50" maxAcceleration="5"
    maxDeceleration="10"/><Axles><FrontAxle maxSteering="0.5" wheelDiameter="0.6" trackWidth="1.5" positionX="2.8"
    positionZ="0.3"/><RearAxle maxSteering="0" wheelDiameter="0.6" trackWidth="1.5" positionX="0" positionZ="0.3"/>
    </Axles><Properties/></Vehicle></ScenarioObject>
  <ScenarioObject name="Kid"><Pedestrian name="kid" pedestrianCategory="pedestrian" mass="20"><BoundingBox>
    <Center x="0" y="0" z="0.6"/><Dimensions width="0.3" length="0.5" height="1.2"/></BoundingBox><Properties/></Pedestrian>
  </ScenarioObject>
</Entities>
<Storyboard><Init><Actions>
  <Private entityRef="Hero">
    <PrivateAction><TeleportAction><Position><LanePosition roadId="7" laneId="-1" s="$EgoS"/></Position>
    </TeleportAction></PrivateAction>
    <PrivateAction><LongitudinalAction><SpeedAction><SpeedActionDynamics dynamicsShape="step" value="0"
      dynamicsDimension="time"/><SpeedActionTarget><AbsoluteTargetSpeed value="2.5"/></SpeedActionTarget>
    </SpeedAction></LongitudinalAction></PrivateAction>
  </Private>
  <Private entityRef="Kid">
    <PrivateAction><TeleportAction><Position><LanePosition roadId="7" laneId="-1" s="$Ahead" offset="-3">
      <Orientation type="relative" h="1.5707963267948966"/></LanePosition></Position></TeleportAction></PrivateAction>
    <PrivateAction><RoutingAction><AssignRouteAction><Route name="across" closed="false">
      <Waypoint routeStrategy="shortest"><Position><LanePosition roadId="7" laneId="-1" s="$Ahead" offset="-3"/>
      </Position></Waypoint>
      <Waypoint routeStrategy="shortest"><Position><LanePosition roadId="7" laneId="-1" s="$Ahead" offset="0"/>
      </Position></Waypoint></Route></AssignRouteAction></RoutingAction></PrivateAction>
  </Private>
</Actions></Init>
<Story name="s"><Act name="a"><ManeuverGroup name="g" maximumExecutionCount="1"><Actors selectTriggeringEntities="false">
  <EntityRef entityRef="Kid"/></Actors><Maneuver name="m"><Event name="go" priority="override">
  <Action name="walk"><PrivateAction><LongitudinalAction><SpeedAction><SpeedActionDynamics dynamicsShape="linear"
    value="1.0" dynamicsDimension="rate"/><SpeedActionTarget><AbsoluteTargetSpeed value="1.5"/></SpeedActionTarget>
  </SpeedAction></LongitudinalAction></PrivateAction></Action>
  <StartTrigger><ConditionGroup><Condition name="c" delay="0" conditionEdge="rising"><ByEntityCondition>
    <TriggeringEntities triggeringEntitiesRule="any"><EntityRef entityRef="Hero"/></TriggeringEntities>
    <EntityCondition><TraveledDistanceCondition value="4"/></EntityCondition></ByEntityCondition></Condition>
  </ConditionGroup></StartTrigger></Event></Maneuver></ManeuverGroup>
  <StartTrigger><ConditionGroup><Condition name="t" delay="0" conditionEdge="none"><ByValueCondition>
    <SimulationTimeCondition value="0" rule="greaterThan"/></ByValueCondition></Condition></ConditionGroup>
  </StartTrigger></Act></Story>
<StopTrigger/></Storyboard></OpenSCENARIO>
"""


def test_a_foreign_file_maps_onto_the_sites_lane(tmp_path, capsys):
    """Another tool's file (a lane position with a parameter expression on its own straight road, a rear-axle
    reference point, a walk across started by the ego's travel, `--param`): its ego lands on the site's lane,
    everything else where it stood relative to the ego, the walk as a co-motion across the lane."""
    import yaml

    from garage_exp.openscenario.xosc_import import main

    (tmp_path / "road.xodr").write_text(FOREIGN_XODR)
    path = tmp_path / "crossing.xosc"
    path.write_text(FOREIGN_XOSC)
    out = tmp_path / "case" / "crossing.yaml"
    assert main([str(path), "-o", str(out), "--param", "EgoS=30"]) == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "ego.speed=9" in printed and "Hero -> ego" in printed
    case = yaml.safe_load(out.read_text())
    ego, kid = case["actors"]["ego"], case["actors"]["kid"]
    assert ego["offset"] == pytest.approx(0.0) and ego["yaw"] == pytest.approx(0.0)
    assert ego["size"] == "medium" and kid["kind"] == "person" and kid["age"] == "child"
    # 12 m ahead of the ego's rear axle: 12 - 1.4 m ahead of its centre, 3 m to its right, facing left
    assert ego["distance"] - kid["distance"] == pytest.approx(12 - 1.4, abs=1e-3)
    assert kid["offset"] - ego["offset"] == pytest.approx(-3.0, abs=1e-3) and kid["yaw"] == pytest.approx(90.0)
    along = case["motion"]["along"]["kid"]
    assert along["key"] == "offset" and along["end"] - along["start"] == pytest.approx(3.0, abs=1e-3)
    assert along["speed"] == 1.5 and along["accelerate"] == pytest.approx(1.125)  # v^2 / 2a
    assert along["at"] == pytest.approx(ego["distance"] - 4.0)
    assert case["motion"]["actor"] == "ego" and case["target"] == "kid"


SYNCHRONISED = """<Action name="walk"><PrivateAction><SynchronizeAction masterEntityRef="Hero">
  <TargetPositionMaster><LanePosition roadId="7" laneId="-1" s="${$Ahead - 2.2 - 0.15}"/></TargetPositionMaster>
  <TargetPosition><LanePosition roadId="7" laneId="-1" s="$Ahead" offset="0"/></TargetPosition>
  <FinalSpeed><AbsoluteSpeed value="1.5"><TargetDistanceSteadyState distance="2"/></AbsoluteSpeed></FinalSpeed>
  </SynchronizeAction></PrivateAction></Action>"""


def test_a_synchronised_walk_becomes_meet_and_the_ego_stops_short(tmp_path, capsys):
    """A SynchronizeAction (Euro NCAP's way to time a pedestrian to the ego): `meet` at the ego's master position
    (its rear axle there, our centre 1.4 m ahead), `accelerate` over the walk less its steady-state distance, and
    the ego's frames end 0.5 m short of the meeting instead of driving into the person."""
    import re

    import yaml

    from garage_exp.openscenario.xosc_import import main

    (tmp_path / "road.xodr").write_text(FOREIGN_XODR)
    text = re.sub(r'<Action name="walk">.*?</Action>', SYNCHRONISED, FOREIGN_XOSC, flags=re.S)
    route = ('<PrivateAction><RoutingAction><AssignRouteAction><Route name="on" closed="false">'
             '<Waypoint routeStrategy="shortest"><Position><LanePosition roadId="7" laneId="-1" s="$EgoS"/></Position>'
             '</Waypoint><Waypoint routeStrategy="shortest"><Position><LanePosition roadId="7" laneId="-1" s="150"/>'
             '</Position></Waypoint></Route></AssignRouteAction></RoutingAction></PrivateAction>\n  </Private>')
    text = text.replace("</Private>", route, 1)  # the ego's route runs on past the person and the lane's end
    path = tmp_path / "sync.xosc"
    path.write_text(text)
    out = tmp_path / "case" / "sync.yaml"
    assert main([str(path), "-o", str(out)]) == 0, capsys.readouterr().err
    case = yaml.safe_load(out.read_text())
    ego, along = case["actors"]["ego"], case["motion"]["along"]["kid"]
    # the master position: the ego's rear axle 2.35 m before the kid's line; its centre 1.4 m further on
    assert along["meet"] == pytest.approx(case["actors"]["kid"]["distance"] + 2.35 - 1.4, abs=1e-3)
    assert along["accelerate"] == pytest.approx(3.0 - 2.0) and along["end"] == pytest.approx(ego["offset"])
    assert "at" not in along
    assert case["motion"]["end"] == pytest.approx(along["meet"] + 0.5)  # 0.5 m short of the meeting
    assert "stops 0.5 m short" in capsys.readouterr().out


ROUND_TRIP_CASES = ["1", "2", "3", "cpnco", "cpra", "crossing", "crouch", "light", "pedestrian", "pullout", "slots", "stepout"]


@pytest.mark.parametrize("case", ROUND_TRIP_CASES)
def test_every_export_imports_back_to_the_job_s_frames_at_three_ego_speeds(case, exported, library, tmp_path):
    """Issue 40: the importer reads every export back (each variant's .xosc) and the imported case builds the
    frames the job built, actor for actor within 5 cm, for a job run at each of three ego speeds (cpra: the
    protocol's reversing speeds, 4 and 8, and 10: from 12 km/h on, its walkers come back 0.19-0.38 m off, a known
    defect in docs/openscenario.md)."""
    import contextlib
    import io

    from garage_exp.openscenario.tracks import variants_of
    from garage_exp.openscenario.xosc_import import main

    speeds = [4, 8, 10] if case == "cpra" else [5, 10, 20]
    for speed in speeds:
        cfg, classified, setup, paths = exported(case, speed)
        variants = variants_of(setup)
        assert len(paths) == len(variants) + 1  # the road file, then one scenario a variant
        for k, ((label, _), xosc) in enumerate(zip(variants, paths[1:])):
            name = f"rt_{case}_{speed}_{k}"
            out = tmp_path / "conf" / "case" / f"{name}.yaml"
            with contextlib.redirect_stdout(io.StringIO()):
                assert main([str(xosc), "-o", str(out), "--name", name]) == 0, (case, speed, label)
            _, _, again = case_setup(library, f"case={name}", f"ego.speed={speed}",
                                     f"hydra.searchpath=[file://{tmp_path / 'conf'}]")
            job = [s for s in setup.shots if s.label == label and s.replicate == 0]
            assert_same_placements(job, [s for s in again.shots if s.replicate == 0])
