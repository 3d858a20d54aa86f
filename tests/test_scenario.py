"""The scenario language: sites, placements, motion, variants, arrangements and their errors, without rendering."""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest
from conftest import compose_cfg

from garage_exp.core.errors import GarageError
from garage_exp.scenario.assemble import build_scene
from garage_exp.core.paths import PROJECT_ROOT
from garage_exp.plan import classify, load_plan
from garage_exp.run.preflight import resolve_plan_path
from garage_exp.scenario.place import footprint, overlap
from garage_exp.scene.description import Pose
from garage_exp.run.spec import scene_spec

CASES = sorted(p.stem for p in (PROJECT_ROOT / "conf" / "case").glob("*.yaml"))
ARRANGEMENTS = sorted(p.stem for p in (PROJECT_ROOT / "conf" / "occluder").glob("*.yaml"))


@pytest.fixture(scope="module")
def library():
    from garage_exp.assets.vehicles import VehicleLibrary

    return VehicleLibrary()


def build(library, *overrides: str, config_dir=None):
    cfg = compose_cfg(*overrides, config_dir=config_dir)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    return build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))


def by_name(scene, name):
    return scene.entity(name)


@pytest.fixture(scope="module")
def arrangement_actors():
    """Each arrangement's actors as its level alone composes them (composed once per module)."""
    return {a: set(compose_cfg(f"occluder={a}").occluder.actors) for a in ARRANGEMENTS}


@pytest.mark.parametrize("case", [c for c in CASES if c != "pedestrian"])
@pytest.mark.parametrize("arrangement", ARRANGEMENTS)
def test_every_shipped_scenario_composes_with_every_arrangement(library, arrangement_actors, case, arrangement):
    """The case placed as a job places it (make_case); where the case is about a pillar (cases 1 and 2) the
    scene too: the arrangement's actors are its only occluders and the pillar made way or stayed."""
    from garage_exp.run.preflight import classified_plan
    from garage_exp.scenario import make_case

    cfg = compose_cfg(f"case={case}", f"occluder={arrangement}")
    classified = classified_plan(resolve_plan_path(cfg.plan))
    setup = make_case(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))
    assert setup.shots
    extra = arrangement_actors[arrangement]
    own = {n for n, a in cfg.case.actors.items() if a.role == "occluder"}  # the case's own (oneshot's)
    assert {v.name for v in setup.vehicles if v.role == "occluder"} == extra | own
    for shot in setup.shots:  # arrangement actors stand still and in every frame
        for name in extra:
            assert shot.poses[name] is not None and shot.poses[name] == setup.shots[0].poses[name]
    if setup.occluder:
        scene, built = build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))
        assert built.shots == setup.shots
        assert {e.name for e in scene.entities if e.role == "occluder"} == extra | own
        if case in ("1", "2") and arrangement in ("none", "vans", "barrier"):
            assert setup.occluder not in {e.name for e in scene.entities}  # the pillar made way
        else:
            assert setup.occluder in {e.name for e in scene.entities}


def test_case_1_default_trajectory(library):
    """The ego approaches the corner 20 m to 4 m before its centre, 0.5 m a step, once per target colour;
    only that colour's car stands, beyond the bend."""
    _, setup = build(library, "case=1")
    black = [s for s in setup.shots if s.label == "black"]
    assert [s.position for s in black] == [20.0 - 0.5 * k for k in range(33)]
    assert {s.target for s in black} == {"target_black"}
    assert all(s.poses["target_white"] is None for s in black)
    steps = [math.hypot(b.ego.x - a.ego.x, b.ego.y - a.ego.y) for a, b in zip(black, black[1:])]
    assert np.allclose(steps, 0.5)
    # the target waits 6 m past the corner, in a lane at a right angle to the ego's
    target = black[0].poses["target_black"]
    assert abs(((target.yaw - black[0].ego.yaw) % 180) - 90) < 1e-9


def test_case_2_passing_car_is_trimmed_to_the_lane(library):
    _, setup = build(library, "case=2")
    positions = [s.position for s in setup.shots if s.label == "black"]
    assert positions == sorted(positions) and positions[0] >= -15.0 and positions[-1] <= 15.0
    assert len({(s.ego.x, s.ego.y) for s in setup.shots}) == 1  # the ego stays in its bay


def test_an_override_reaches_any_actor_value(library):
    _, base = build(library, "case=light", "case.motion.values=[8.0]")
    _, moved = build(library, "case=light", "case.motion.values=[8.0]", "case.actors.target.offset=0.4",
                     "case.actors.target.yaw=5")
    a, b = base.shots[0].poses["target_black"], moved.shots[0].poses["target_black"]
    assert math.isclose(math.hypot(b.x - a.x, b.y - a.y), 0.4, abs_tol=1e-9)
    assert math.isclose((b.yaw - a.yaw) % 360, 5.0, abs_tol=1e-9)


def test_a_variant_sets_values_for_its_frames_only(library):
    _, setup = build(library, "case=light", "palette.target_colours=[black]", "case.actors.target.colour=black",
                     "case.motion.values=[8.0]",
                     "case.variants=[{label: near},{label: shifted, set: {target.offset: 1.0}}]")
    near, shifted = setup.shots
    assert (near.label, shifted.label) == ("near", "shifted")
    a, b = near.poses["target"], shifted.poses["target"]
    assert math.isclose(math.hypot(b.x - a.x, b.y - a.y), 1.0, abs_tol=1e-9)


def test_arrangement_cars_take_free_bays_and_fit_them(library):
    scene, setup = build(library, "case=2", "occluder=pillar_cars")
    ego = setup.shots[0].ego
    cars = [e for e in scene.entities if e.role == "occluder"]
    assert len(cars) == 2
    for car in cars:
        assert math.hypot(car.pose.x - ego.x, car.pose.y - ego.y) > 2.0  # not in the ego's bay


def test_footprint_overlap():
    a = footprint(Pose(0, 0, 0, 0), (4.0, 2.0, 1.5))
    assert overlap(a, footprint(Pose(3.0, 0, 0, 0), (4.0, 2.0, 1.5)))
    assert not overlap(a, footprint(Pose(4.1, 0, 0, 0), (4.0, 2.0, 1.5)))
    assert overlap(a, footprint(Pose(0, 1.5, 0, 90), (4.0, 2.0, 1.5)))  # crossing at a right angle
    assert not overlap(a, footprint(Pose(0, 3.1, 0, 90), (4.0, 2.0, 1.5)))


def test_a_users_own_scenario_and_site_run_with_no_change_to_the_package(library, tmp_path, monkeypatch):
    (tmp_path / "case").mkdir()
    (tmp_path / "case" / "cut_in.yaml").write_text(textwrap.dedent("""\
        name: cut_in
        site: {_target_: my_sites.ramp, lane: lane}
        position_label: lateral offset of the car ahead (m)
        actors:
          ego: {role: ego, model: "${palette.ego}", path: up, distance: 2.0}
          target: {role: target, size: medium, colour: red, relative: ego, distance: 9.0}
        motion: {actor: target, key: offset, start: 2.0, end: 0.0, step: 1.0}
        """))
    (tmp_path / "my_sites.py").write_text(textwrap.dedent("""\
        from garage_exp.scenario.sites import Path, Site, straight_run

        def ramp(classified, garage, lane):
            lane = straight_run(classified, garage).paths[lane]
            return Site("ramp", {"up": lane})
        """))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("GARAGE_EXP_MODIFIER_MODULES", "my_sites")
    _, setup = build(library, "case=cut_in", config_dir=tmp_path)
    assert [s.position for s in setup.shots] == [2.0, 1.0, 0.0]
    ego = setup.shots[0].ego
    gaps = [math.hypot(s.poses["target"].x - ego.x, s.poses["target"].y - ego.y) for s in setup.shots]
    assert np.allclose(gaps, [math.hypot(9.0, o) for o in (2.0, 1.0, 0.0)])
    monkeypatch.delenv("GARAGE_EXP_MODIFIER_MODULES")
    with pytest.raises(GarageError, match="cut_in.*case.site: 'my_sites.ramp' is not a site function"):
        build(library, "case=cut_in", config_dir=tmp_path)
    # the old form, a bare dotted name, is refused with the new one
    with pytest.raises(GarageError, match=r"case.site: site 'my_sites.ramp' names a function: write it as site: "
                                          r"\{_target_: my_sites.ramp\}"):
        build(library, "case=cut_in", "case.site=my_sites.ramp", config_dir=tmp_path)


def test_the_docs_scenario_example_builds_as_it_says(library, tmp_path):
    import re

    page = (PROJECT_ROOT / "docs" / "scenarios.md").read_text()
    start = re.search(r"Save it as\s+`my_conf/case/cut_in.yaml`", page).start()
    (tmp_path / "case").mkdir()
    (tmp_path / "case" / "cut_in.yaml").write_text(re.search(r"```yaml\n(.*?)```", page[start:], re.S).group(1))
    _, setup = build(library, "case=cut_in", config_dir=tmp_path)
    assert [s.label for s in setup.shots] == ["10 m"] * 5 + ["15 m"] * 5
    assert [s.position for s in setup.shots[:5]] == [2.0, 1.5, 1.0, 0.5, 0.0]
    ego = setup.shots[0].ego
    ahead = [math.hypot(s.poses["car"].x - ego.x, s.poses["car"].y - ego.y) for s in setup.shots if s.position == 0]
    assert np.allclose(ahead, [10.0, 15.0])
    assert all(s.poses["van"] == setup.shots[0].poses["van"] for s in setup.shots)
    with pytest.raises(GarageError, match="a variant sets an actor's placement"):
        build(library, "case=cut_in", "case.variants=[{set: {car.body: van}}]", config_dir=tmp_path)


def write_case(folder, text: str) -> None:
    (folder / "case").mkdir(exist_ok=True)
    (folder / "case" / "mine.yaml").write_text(textwrap.dedent(text))


def test_a_t_junction_site_puts_a_crossing_car_on_the_through_lane(library, tmp_path):
    write_case(tmp_path, """\
        name: mine
        site: t_junction
        actors:
          ego: {role: ego, model: "${palette.ego}", path: stem, distance: 12.0}
          target: {role: moving, size: medium, colour: red, path: left, distance: 8.0, yaw: 180}
        target: target
        """)
    _, setup = build(library, "case=mine", "plan=research", config_dir=tmp_path)
    shot, = setup.shots
    ego, car = shot.ego, shot.poses["target"]
    assert math.isclose(math.hypot(car.x - ego.x, car.y - ego.y), math.hypot(12.0, 8.0), abs_tol=1e-6)
    assert abs(((car.yaw - ego.yaw) % 360) - 270) < 1e-9  # comes from the ego's left, driving to its right
    # the car is on the ego's left: the cross product of the heading and the offset is positive
    hx, hy = math.cos(math.radians(ego.yaw)), math.sin(math.radians(ego.yaw))
    assert hx * (car.y - ego.y) - hy * (car.x - ego.x) > 7.9


def test_bays_on_either_side_of_the_straight_run(library, tmp_path):
    write_case(tmp_path, """\
        name: mine
        site: straight_run
        actors:
          ego: {role: ego, model: "${palette.ego}", path: lane, distance: 2.0}
          a: {role: target, size: medium, bay: "left:4"}
          b: {role: parked, size: medium, bay: "right:4"}
        """)
    from garage_exp.scenario.sites import straight_run

    cfg = compose_cfg("plan=realistic")
    site = straight_run(classify(load_plan(resolve_plan_path(cfg.plan))), cfg.garage)
    if len(site.sides) < 2:
        pytest.fail(f"the realistic plan's longest straight run should have bays on both sides: {site.sides}")
    _, setup = build(library, "case=mine", "plan=realistic", config_dir=tmp_path)
    ego, a, b = setup.shots[0].ego, setup.shots[0].poses["a"], setup.shots[0].poses["b"]
    hx, hy = math.cos(math.radians(ego.yaw)), math.sin(math.radians(ego.yaw))
    side = [hx * (p.y - ego.y) - hy * (p.x - ego.x) for p in (a, b)]
    assert side[0] > 2.0 and side[1] < -2.0
    with pytest.raises(GarageError, match="no bay 'middle:1'"):
        build(library, "case=mine", "plan=realistic", "case.actors.b.bay=middle:1", config_dir=tmp_path)
