"""The blank control under the real look (issue 47, item 12): the target vehicle alone, same pose and camera, with
the garage removed: grey 128 everywhere but the car and its own contact shadow, under the look's studio light
(`look.blank_light`), so that no light preset changes it. docs/results.md has the measured factors."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROOT, compose_cfg, require
from garage_exp.run.spec import scene_spec

pytestmark = [pytest.mark.render]

SMALL = ["case=light", "case.motion.values=[8.0]", "palette.target_colours=[white]", "camera.width=320",
         "camera.height=240", "sensor=ideal"]  # the frames as rendered and composited, before any camera


def frame(*overrides: str):
    """The light case's one shot, through the job's frame pipeline (ideal camera): its `Rendered`."""
    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.perception.sensor import make_sensor
    from garage_exp.plan import classify, load_plan
    from garage_exp.render.sapien_backend import get_renderer
    from garage_exp.run.pipeline import FramePipeline
    from garage_exp.scenario.assemble import build_scene

    require("vulkan", "vehicles")
    cfg = compose_cfg(*SMALL, *overrides)
    classified = classify(load_plan(ROOT / "plans" / f"{cfg.plan.name}.yaml"))
    scene, setup = build_scene(scene_spec(cfg), classified, VehicleLibrary(), np.random.default_rng(cfg.seed))
    renderer = get_renderer(max_lights=cfg.renderer.max_lights)
    renderer.load(scene)
    pipeline = FramePipeline(cfg, scene, renderer, make_sensor(), np.random.default_rng(0))
    (item,) = pipeline.frames(setup.shots)
    return item


@pytest.fixture(scope="module")
def frames():
    return {(light, blank): frame(f"light={light}", f"blank={blank}") for light in ("bright", "dim")
            for blank in ("false", "true")}


def outside_target(item) -> np.ndarray:
    x1, y1, x2, y2 = item.target.full_box
    out = np.ones(item.rgb.shape[:2], bool)
    out[y1:y2, x1:x2] = False
    return out


def test_the_blank_frame_is_the_car_and_its_shadow_on_grey(frames):
    """No garage pixel is left: outside the car every pixel is neutral grey, 128 above the horizon (nothing but
    the backdrop can be there) and no lighter below it; the car keeps its own contact shadow, a darkening of
    the grey under and beside it. The garage frame of the same shot fails the same checks."""
    blank, garage = frames[("bright", "true")], frames[("bright", "false")]
    rgb, outside = blank.rgb.astype(int), outside_target(blank)
    off = rgb[outside]
    assert np.all(off[:, 0] == off[:, 1]) and np.all(off[:, 1] == off[:, 2])  # no colour: no garage
    assert rgb[outside].max() == 128
    horizon = blank.rgb.shape[0] // 2  # a level camera: the floor lies below the middle row
    assert np.all(rgb[:horizon - 1][outside[:horizon - 1]] == 128)
    x1, y1, x2, y2 = blank.target.full_box
    beside = rgb[y2 - 4:y2 + 2, max(0, x1 - 6):x1, 0]  # beside the wheels, where the shadow reaches past the car
    assert beside.min() < 100, beside  # the contact shadow
    g = garage.rgb.astype(int)[outside_target(garage)]
    assert not np.all(g[:, 0] == g[:, 2]) and g.max() > 128


def test_the_blank_control_does_not_move_with_the_light(frames):
    """The light preset changes the garage frame, never the blank one (the research's blank hardly moves with
    the light: 0.88-0.91 across the four presets)."""
    assert np.array_equal(frames[("bright", "true")].rgb, frames[("dim", "true")].rgb)
    assert np.abs(frames[("bright", "false")].rgb.astype(int) - frames[("dim", "false")].rgb.astype(int)).mean() > 5


def test_the_flat_look_keeps_the_blank_it_published():
    """The flat look's blank (golden tables) is lit by the preset and has no shadow: uniform 128 off the car."""
    item = frame("look=flat", "light=dim", "blank=true")
    assert np.all(item.rgb[outside_target(item)] == 128)
