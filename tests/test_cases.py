"""The cases as the experiment builds them (garage_exp.run.frames.build_scene: scene + shots); geometry only.
Case 2 as a user runs it: tests/test_jobs.py::test_case_2_runs_the_same_with_serial_and_overlapped_detection."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import ROOT, compose_cfg, require

from garage_exp.plan.classify import LANE_TYPES
from garage_exp.run.spec import scene_spec


@pytest.fixture(scope="module")
def library():
    require("vehicles")
    from garage_exp.assets.vehicles import VehicleLibrary

    return VehicleLibrary()


def job_plan(cfg):
    """The plan a job of `cfg` runs on (a shipped one, or a generator's draw with its garage handed on)."""
    from garage_exp.run.preflight import classified_plan, hand_on, resolve_plan_path

    classified = classified_plan(resolve_plan_path(cfg.plan))
    hand_on(cfg, classified.plan)
    return classified


def build(library, *overrides: str):
    from garage_exp.scenario.assemble import build_scene

    cfg = compose_cfg(*overrides)
    classified = job_plan(cfg)
    scene, setup = build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))
    return cfg, classified, scene, setup


def case_setup(library, *overrides: str):
    """The case as a job places it (scenario.make_case, as build_scene calls it, on the same seed's draws), without
    building the garage around it: for the tests of placements, exports and imports, which never look at the
    scene (cfg, classified plan, setup)."""
    from garage_exp.scenario import make_case

    cfg = compose_cfg(*overrides)
    classified = job_plan(cfg)
    return cfg, classified, make_case(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))


def on_lane(classified, pose) -> bool:
    cell = classified.plan.cell_at(pose.x, pose.y)
    return cell is not None and classified.cell(*cell).type in LANE_TYPES


def test_case_1_default_trajectory(library):
    """Case 1 as configured: per target colour, the ego drives along one lane 0.5 m per step towards the corner
    (from case.motion.start, or as far back as the lane allows, to case.motion.end), the target waits beyond the bend."""
    cfg, classified, scene, setup = build(library)
    colours = list(cfg.palette.target_colours)
    assert [s.label for s in setup.shots] == [c for c in colours for _ in range(len(setup.shots) // len(colours))]
    for colour in colours:
        shots = [s for s in setup.shots if s.label == colour]
        positions = [s.position for s in shots]
        assert positions[0] <= cfg.case.motion.start and positions[-1] == pytest.approx(cfg.case.motion.end)
        assert np.allclose(np.diff(positions), -cfg.case.motion.step)
        assert len(shots) >= 20  # the research plan's lane is long enough for most of the 20 m approach
        egos = np.array([(s.ego.x, s.ego.y) for s in shots])
        steps = np.linalg.norm(np.diff(egos, axis=0), axis=1)
        assert np.allclose(steps, cfg.case.motion.step)  # moves as far as the position says
        assert len({round(s.ego.yaw, 6) for s in shots}) == 1  # one heading: a straight drive
        assert all(on_lane(classified, s.ego) for s in shots)
        target = {(p.x, p.y, p.yaw) for s in shots for n, p in s.poses.items() if n == s.target}
        assert len(target) == 1 and all(s.target == f"target_{colour}" for s in shots)
        tx, ty, tyaw = target.pop()
        assert on_lane(classified, next(iter(shots)).poses[f"target_{colour}"])
        assert abs(((tyaw - shots[0].ego.yaw) + 180) % 360 - 180) == pytest.approx(90)  # beyond the bend
        dist = np.hypot(egos[:, 0] - tx, egos[:, 1] - ty)
        assert np.all(np.diff(dist) < 0)  # the ego closes in on the target
        others = [p for s in shots for n, p in s.poses.items() if n != s.target]
        assert all(p is None for p in others)  # one target in the scene at a time
    assert setup.occluder in {e.name for e in scene.entities}


def test_case_1_without_the_pillar_removes_it(library):
    _, _, scene, setup = build(library, "occluder=none")
    assert setup.occluder and setup.occluder not in {e.name for e in scene.entities}


def test_case_2_is_built_with_a_car_passing_a_parked_ego(library):
    """Case 2: the ego stands still in a bay beside the pillar; the target passes across its view, 0.5 m per
    step, on one straight line in the lane, from one side of the ego's axis to the other."""
    cfg, classified, scene, setup = build(library, "case=2")
    assert setup.shots and setup.occluder in {e.name for e in scene.entities}
    assert len({(s.ego.x, s.ego.y, s.ego.yaw) for s in setup.shots}) == 1
    ego = setup.shots[0].ego
    assert not on_lane(classified, ego)  # parked in a bay
    for colour in cfg.palette.target_colours:
        shots = [s for s in setup.shots if s.label == colour]
        poses = np.array([(s.poses[s.target].x, s.poses[s.target].y) for s in shots])
        assert np.allclose(np.linalg.norm(np.diff(poses, axis=0), axis=1), cfg.case.motion.step)
        assert np.allclose(np.diff([s.position for s in shots]), cfg.case.motion.step)
        assert all(on_lane(classified, s.poses[s.target]) for s in shots)
        heading = (math.cos(math.radians(ego.yaw)), math.sin(math.radians(ego.yaw)))
        side = (poses[:, 0] - ego.x) * -heading[1] + (poses[:, 1] - ego.y) * heading[0]
        assert side.min() < -3 and side.max() > 3  # crosses the ego's axis
        ahead = (poses[:, 0] - ego.x) * heading[0] + (poses[:, 1] - ego.y) * heading[1]
        assert np.all(ahead > 0) and np.ptp(ahead) < 1e-6  # in front, on a line across the view
    pillar = next(e for e in scene.entities if e.name == setup.occluder)
    assert math.hypot(pillar.pose.x - ego.x, pillar.pose.y - ego.y) < 5  # the pillar is beside the ego


PLANS = sorted(p.stem for p in (ROOT / "conf" / "plan").glob("*.yaml") if p.stem != "tiny")
CASES = sorted(p.stem for p in (ROOT / "conf" / "case").glob("*.yaml"))


@pytest.mark.parametrize("case, plan", [(c, p) for c in CASES for p in PLANS])
def test_every_case_is_built_on_every_experiment_plan(library, plan, case):
    """The product's own feature finders find each case's feature on each shipped plan: the case has its
    vehicles and the shots place only those (the scene they go into: the next test)."""
    _, classified, setup = case_setup(library, f"plan={plan}", f"case={case}")
    names = {v.name for v in setup.vehicles}
    assert setup.shots and all(s.target in names for s in setup.shots)
    assert all(n in names for s in setup.shots for n in s.poses)
    assert all(on_lane(classified, s.ego) or case == "2" for s in setup.shots)


@pytest.mark.parametrize("plan", PLANS)
def test_the_scene_holds_the_case_s_vehicles_on_every_experiment_plan(library, plan):
    """build_scene on each shipped plan places the case as make_case does (the previous test's setup: same
    shots) and puts every one of its vehicles into the scene (case 3: the most vehicles)."""
    from garage_exp.scenario import make_case
    from garage_exp.scenario.assemble import build_scene

    cfg = compose_cfg(f"plan={plan}", "case=3")
    classified = job_plan(cfg)
    scene, setup = build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))
    alone = make_case(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))
    assert setup.shots == alone.shots
    names = {e.name for e in scene.entities}
    assert {v.name for v in setup.vehicles} <= names
    assert all(s.target in names and all(n in names for n in s.poses) for s in setup.shots)


def spread(items: list) -> list:
    """All of `items`, the middle one first, then those at the quarters, the eighths, ...: a run of neighbouring
    frames where the target is fair (between too small or hidden far away and cut off near) is met after a few."""
    order, parts = [], 2
    while parts <= 2 * len(items):
        order += [k for k in (m * len(items) // parts for m in range(1, parts, 2)) if k not in order]
        parts *= 2
    return [items[k] for k in order] + [item for k, item in enumerate(items) if k not in order]


RIG = {"slots": ["camera=fisheye4"], "cpra": ["camera=rear"]}  # cases scored by a camera the front rig lacks


@pytest.mark.render
@pytest.mark.slow
def test_every_shipped_case_has_a_fair_frame_on_the_small_plan():
    """Issue 31, item 11: on plan=small every shipped case builds and, with its own settings, some frame is a fair
    test of the detector (the search's rule). Ground truth only, at a quarter of the resolution (the box rule
    scaled with it), every camera of the rig (the slot case's parked target is behind the ego). The shots in
    `spread` order, until the first fair frame: a case none of whose frames is fair still renders them all, and
    fails."""
    from types import SimpleNamespace

    import pandas as pd
    from omegaconf import OmegaConf

    from garage_exp.core.plugins import build as build_plugin
    from garage_exp.render.open import open_renderer
    from garage_exp.scenario.assemble import HIDDEN
    from garage_exp.results.table import fair_mask, frame_row
    from garage_exp.run.pipeline import render_frames
    from garage_exp.run.preflight import preflight
    from garage_exp.scenario.fits import CASES, FITS
    from garage_exp.search.prescreen import cheap_config

    require("vulkan", "vehicles")
    assert set(CASES) <= set(globals()["CASES"]) and FITS["small"] == CASES
    scale, unscored = 0.25, SimpleNamespace(per_model=[], composite=0.0, detected=False, false_positives=0)
    fair, rendered = {}, {}
    for case in CASES:
        cfg = cheap_config(compose_cfg("plan=small", f"case={case}", *RIG.get(case, [])),
                           scale)
        prepared = preflight(cfg, check_space=False, load=False)  # ground truth only: no detector loaded
        renderer = open_renderer(cfg.renderer, HIDDEN)
        renderer.load(prepared.scene)
        sensor = build_plugin(cfg.sensor, "a sensor model", "sensor._target_")
        rule = OmegaConf.create({**OmegaConf.to_container(cfg.search), "min_box": cfg.search.min_box * scale})
        shots = spread(prepared.setup.shots)
        fair[case] = rendered[case] = 0
        for item in render_frames(cfg, prepared.scene, shots, renderer, sensor, np.random.default_rng(0)):
            rendered[case] += 1
            row = frame_row(item.shot, item.camera, item.target, unscored, [])
            if fair_mask(pd.DataFrame([row]), rule).all():
                fair[case] = 1
                break
    assert all(fair.values()), (fair, rendered)


def test_a_case_on_a_shipped_plan_it_does_not_fit_names_the_plans_that_fit():
    from garage_exp.scenario.fits import FITS, hint

    assert set(FITS) <= {p.stem for p in (ROOT / "conf" / "plan").glob("*.yaml")}
    assert hint("3", "tiny", None).startswith("case=3 does not fit plan=tiny; it fits plan=small, research")
    assert hint("3", "small", None) == hint("3", "tiny", "/my/plan.yaml") == hint("mine", "tiny", None) == ""
    # case 1 builds on the tiny plan (no fair frame): a refusal there (missing assets, say) is not about fitting
    assert hint("1", "tiny", None, refused=True) == "" and hint("1", "tiny", None).startswith("case=1 does not fit")
