"""One-shot scenarios (issue 49, item 5): `case.frames=K` keeps K of a trajectory's frames, and a search of one-shot
trials with `search.runs=per_search` (one MLflow run per search, the scenarios' rows on it) reproduces its rows."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import compose_cfg

from garage_exp.core.errors import GarageError
from garage_exp.plan import classify, load_plan
from garage_exp.run.preflight import resolve_plan_path
from garage_exp.scenario.assemble import build_scene
from garage_exp.scenario.build import one_shot


@pytest.fixture(scope="module")
def library():
    from garage_exp.assets.vehicles import VehicleLibrary

    return VehicleLibrary()


def shots(library, *overrides: str):
    cfg = compose_cfg(*overrides)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    return build_scene(cfg, classified, library, np.random.default_rng(cfg.seed))[1].shots


def test_one_shot_picks_evenly_spaced_frames_ends_included():
    assert one_shot(5, None) == {0, 1, 2, 3, 4}
    assert one_shot(5, 9) == {0, 1, 2, 3, 4}
    assert one_shot(5, 1) == {0}
    assert one_shot(5, 2) == {0, 4}
    assert one_shot(33, 3) == {0, 16, 32}


def test_a_k_frame_scenario_is_k_of_the_trajectorys_own_frames(library):
    """case=1's trajectory (33 frames a colour, the ego driving): frames=3 keeps its first, middle and last frame
    with the same ego and target poses and the same times; frames=1 its first."""
    full = [s for s in shots(library, "case=1") if s.label == "black"]
    three = [s for s in shots(library, "case=1", "case.frames=3") if s.label == "black"]
    assert [s.position for s in three] == [full[k].position for k in (0, 16, 32)] == [20.0, 12.0, 4.0]
    for got, want in zip(three, (full[0], full[16], full[32])):
        assert (got.ego, got.time, got.poses["target_black"]) == (want.ego, want.time, want.poses["target_black"])
    one = shots(library, "case=1", "case.frames=1", "palette.target_colours=[black]")
    assert [(s.position, s.label) for s in one] == [(20.0, "black")]


def test_a_static_case_is_one_shot_already(library):
    """A case without a motion actor is one frame a variant whatever frames says (1 frame: nothing to drop)."""
    assert len(shots(library, "case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]",
                     "case.frames=1")) == 1


@pytest.mark.parametrize("bad", ["0", "-2"])
def test_frames_below_one_is_refused_naming_the_key(library, bad):
    with pytest.raises(GarageError, match=r"case\.frames.*frames must be a whole number >= 1"):
        shots(library, "case=1", f"case.frames={bad}")


def rendered(scene, setup, renderer, cfg) -> np.ndarray:
    from garage_exp.core.plugins import build
    from garage_exp.run.pipeline import FramePipeline, in_view

    sensor = build(cfg.sensor, "a sensor model", "sensor._target_")
    shot = setup.shots[0]
    pipeline = FramePipeline(cfg, scene, renderer, sensor, np.random.default_rng(7))
    return next(iter(pipeline.shots([shot], [scene.cameras[0].name], [in_view(scene, shot.poses)],
                                    [pipeline.sensor_rng]))).rgb


@pytest.mark.render
def test_a_kept_garage_taken_back_renders_what_a_fresh_load_renders(library):
    """renderer.kept_garages=3: plan A, then plan B, then A again with other actors and light: A's SAPIEN scene is
    taken back (not rebuilt) and its frame is pixel-equal to the same scene loaded into a fresh renderer."""
    from conftest import require

    require("vulkan", "vehicles")
    from garage_exp.core.state import STATE
    from garage_exp.render.sapien_backend import get_renderer

    base = ("case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]", "camera.width=96",
            "camera.height=72", "look=flat")

    def built(*more):
        cfg = compose_cfg(*base, *more)
        classified = classify(load_plan(resolve_plan_path(cfg.plan)))
        return cfg, *build_scene(cfg, classified, library, np.random.default_rng(cfg.seed))

    first, again, other = built("plan=small"), built("plan=small", "case.actors.target.distance=6.5",
                                                    "light.intensity=0.4"), built("plan=obstacles")
    STATE.renderer = None
    renderer = get_renderer()
    renderer.kept_garages = 3
    renderer.load(first[1])
    kept = renderer.sapien_scene
    rendered(first[1], first[2], renderer, first[0])
    renderer.load(other[1])
    assert renderer.sapien_scene is not kept
    renderer.load(again[1])
    assert renderer.sapien_scene is kept  # taken back, not rebuilt
    taken_back = rendered(again[1], again[2], renderer, again[0])
    STATE.renderer = None  # a fresh renderer, as a new process has
    fresh = get_renderer()
    fresh.load(again[1])
    assert np.array_equal(taken_back, rendered(again[1], again[2], fresh, again[0]))
    assert taken_back.std() > 0  # a picture, not a blank
    STATE.renderer = None
    one = get_renderer()  # kept_garages=1 (today): the last garage only, another one is rebuilt
    one.load(first[1])
    was = one.sapien_scene
    one.load(other[1])
    one.load(first[1])
    assert one.sapien_scene is not was
