"""The wide space (conf/space/wide.yaml, issue 49 item 3): each factor moves the scene description (or the sensor's
output) the way its key promises, the one-shot case it draws on, and the `space` group a search reads as if its
entries were written on the command line. Scene descriptions only (no rendering)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import compose_cfg
from omegaconf import OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.run.spec import scene_spec

BASE = ("case=oneshot", "plan=small")


def built(*overrides):
    """The one-shot scene (scene description, case set-up) as a job builds it, on the small plan."""
    from garage_exp.assets.vehicles import shared_library
    from garage_exp.plan import classify, load_plan
    from garage_exp.run.preflight import check_config, resolve_plan_path
    from garage_exp.scenario.assemble import build_scene

    cfg = compose_cfg(*BASE, *overrides)
    check_config(cfg)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    return build_scene(scene_spec(cfg), classified, shared_library(), np.random.default_rng(cfg.seed))


def shot(*overrides):
    scene, setup = built(*overrides)
    assert len(setup.shots) == 1  # a one-shot scenario: one frame
    return scene, setup, setup.shots[0]


def entity(scene, name):
    return next(e for e in scene.entities if e.name == name)


def ahead(pose, ego):
    """How far `pose` stands ahead of the ego along the lane (+x on the small plan's longest lane) and to its left."""
    return pose.x - ego.x, pose.y - ego.y


# -- the one-shot case ----------------------------------------------------------------------------------------------

def test_the_oneshot_case_is_one_frame_with_the_target_ahead_and_the_occluder_between():
    scene, setup, s = shot()
    ego, target, occluder = s.ego, s.poses["target"], s.poses["occluder"]
    assert ahead(target, ego) == pytest.approx((12.0, 0.0))
    assert 0 < ahead(occluder, ego)[0] < 12.0
    assert entity(scene, "occluder").kind == "box" and entity(scene, "target").kind == "vehicle"


def test_a_target_past_the_lanes_end_stops_at_its_end_never_in_the_wall():
    _, setup, near = shot("case.actors.target.distance=25")
    _, _, far = shot("case.actors.target.distance=80")
    assert far.poses["target"].x == pytest.approx(near.poses["target"].x)  # both at the end of the lane's room
    assert ahead(far.poses["target"], far.ego)[0] < 80


# -- the target ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind, expect", [("tcamryred", ("vehicle", "tcamryred")), ("child", ("person", "child")),
                                          ("adult", ("person", "adult")), ("pillar", ("box", None))])
def test_one_key_says_what_the_target_is(kind, expect):
    scene, _, _ = shot(f"case.actors.target.type={kind}")
    target = entity(scene, "target")
    assert target.kind == expect[0]
    if kind.startswith("tcamry"):
        assert target.model == expect[1]
    elif expect[1]:
        assert target.size_class == expect[1]  # a person's size class is its age group


def test_a_crouching_target_is_an_adult_crouching():
    from garage_exp.scenario.schema import ActorConf
    from garage_exp.scenario.actors import resolve_type

    actor = resolve_type(ActorConf(type="crouching", pose="walking"))
    assert (actor.kind, actor.age, actor.pose) == ("person", "adult", "crouching")
    assert resolve_type(ActorConf(type="child", pose="walking")).pose == "walking"  # a child keeps its pose key
    with pytest.raises(GarageError, match="case.actors.type: type 'person' is a kind"):
        resolve_type(ActorConf(type="person"))


def test_an_unknown_model_named_by_type_is_refused_naming_the_key():
    with pytest.raises(GarageError, match="oneshot.yaml"):
        built("case.actors.target.type=batmobile")


def test_hue_and_lightness_paint_the_target():
    scene, _, _ = shot("case.actors.target.hue=0", "case.actors.target.saturation=0.8",
                       "case.actors.target.lightness=0.5")
    red = entity(scene, "target").shapes[0].paint
    assert red[0] > 5 * red[1] and red[0] > 5 * red[2]  # hue 0: red
    scene, _, _ = shot("case.actors.target.hue=240", "case.actors.target.saturation=0.8",
                       "case.actors.target.lightness=0.5")
    blue = entity(scene, "target").shapes[0].paint
    assert blue[2] > 5 * blue[0]
    scene, _, _ = shot("case.actors.target.lightness=0.85")
    light = entity(scene, "target").shapes[0].paint
    assert sum(light) > 2 * sum(red)  # lighter paint
    scene, _, _ = shot()
    assert entity(scene, "target").shapes[0].paint is None  # no key: the model's own paint


def test_paint_out_of_range_is_refused():
    with pytest.raises(GarageError, match="case.actors.target.hue: hue 400 is outside 0-360"):
        built("case.actors.target.hue=400")


@pytest.mark.parametrize("key, value, moved", [("distance", 8.0, (8.0, 0.0)), ("offset", 1.5, (12.0, 1.5))])
def test_distance_and_offset_place_the_target(key, value, moved):
    _, _, s = shot(f"case.actors.target.{key}={value}")
    assert ahead(s.poses["target"], s.ego) == pytest.approx(moved)


def test_yaw_turns_the_target():
    _, _, s = shot("case.actors.target.yaw=90")
    assert s.poses["target"].yaw == pytest.approx((s.ego.yaw + 90) % 360)


def test_stature_spans_each_age_groups_heights():
    from garage_exp.assets.people import STATURE
    from garage_exp.scenario.schema import ActorConf
    from garage_exp.scenario.actors import height_of

    assert height_of(ActorConf(age="adult", stature=0.0), "x") == pytest.approx(STATURE["adult"][0], abs=0.025)
    assert height_of(ActorConf(age="adult", stature=1.0), "x") == pytest.approx(STATURE["adult"][1], abs=0.025)
    assert len({height_of(ActorConf(age="adult", stature=k / 100), "x") for k in range(101)}) <= 9  # 5 cm steps
    assert height_of(ActorConf(age="child", stature=0.5), "x") < height_of(ActorConf(age="adult", stature=0.0), "x")
    assert height_of(ActorConf(age="adult", height=1.7), "x") == 1.7  # no stature: `height` as written
    with pytest.raises(GarageError, match="x.stature"):
        height_of(ActorConf(stature=1.5), "x")


# -- the occluder and the parked cars --------------------------------------------------------------------------------

@pytest.mark.parametrize("gap", [0.5, 4.0])
def test_the_occluder_stands_gap_metres_of_free_floor_before_the_target(gap):
    scene, _, s = shot(f"case.actors.occluder.gap={gap}", "case.actors.occluder.length=0.8")
    target, occluder = s.poses["target"], s.poses["occluder"]
    free = (target.x - entity(scene, "target").extent[0] / 2) - (occluder.x + 0.8 / 2)
    assert free == pytest.approx(gap)
    assert entity(scene, "occluder").extent[:2] == (0.8, 0.8)  # `length` is a pillar's side: width follows


def test_a_turned_target_keeps_the_gap_to_its_footprint():
    scene, _, s = shot("case.actors.target.yaw=90", "case.actors.occluder.gap=1.0", "case.actors.occluder.length=0.6")
    half_width = entity(scene, "target").extent[1] / 2  # side-on: its width faces the ego
    assert s.poses["target"].x - half_width - (s.poses["occluder"].x + 0.3) == pytest.approx(1.0)


def test_the_occluder_may_be_a_car_stopped_in_the_lane():
    scene, _, _ = shot("case.actors.occluder.type=van_silver", "case.actors.occluder.offset=2.5")
    assert (entity(scene, "occluder").kind, entity(scene, "occluder").model) == ("vehicle", "van_silver")


def test_parked_occupancy_fills_more_bays():
    few = len(built("palette.parked_occupancy=0.1")[0].by_role("parked"))
    many = len(built("palette.parked_occupancy=0.9")[0].by_role("parked"))
    assert many > few


# -- the ego and its camera ---------------------------------------------------------------------------------------

def camera_world(scene, s):
    """The camera's world position and heading (degrees) in the shot: the ego's pose composed with the mount."""
    cam = scene.cameras[0]
    world = s.ego.compose(cam.mount)
    return world, cam


def test_ego_heading_error_turns_the_camera():
    scene, _, s0 = shot()
    scene7, _, s7 = shot("case.actors.ego.yaw=7")
    assert camera_world(scene7, s7)[0].yaw == pytest.approx((camera_world(scene, s0)[0].yaw + 7) % 360)


def test_ego_lateral_position_moves_the_camera_sideways():
    scene, _, s0 = shot()
    scene1, _, s1 = shot("case.actors.ego.offset=0.8")
    assert camera_world(scene1, s1)[0].y - camera_world(scene, s0)[0].y == pytest.approx(0.8)


def test_camera_height_pitch_and_fov():
    scene, _, s = shot("camera.mount=bumper", "camera.z=0.0")
    low = camera_world(scene, s)[0].z
    scene, _, s = shot("camera.mount=bumper", "camera.z=1.0", "camera.pitch=8", "camera.fovy=40")
    world, cam = camera_world(scene, s)
    assert 0.5 <= low <= 0.6 and world.z == pytest.approx(low + 1.0)  # 0.5-1.5 m above the floor
    assert (cam.pitch, cam.fovy) == (8.0, 40.0)


# -- the light ----------------------------------------------------------------------------------------------------

def test_colour_temperature_2000_k_gives_lamps_redder_than_6500_k():
    sodium = built("light.temperature=2000")[0].lights[0].color
    daylight = built("light.temperature=6500")[0].lights[0].color
    assert sodium[0] / sodium[2] > 10 * daylight[0] / daylight[2]
    assert daylight == pytest.approx((1.0, 1.0, 1.0), abs=0.07)  # 6500 K is about white
    default = built()[0].lights[0].color
    assert default == pytest.approx((1.0, 0.96, 0.9))  # no temperature: light.colour as written


def test_colour_temperature_outside_the_lamps_range_is_refused():
    from garage_exp.scene.lamps import check_light

    with pytest.raises(GarageError, match="light.temperature: temperature = 500 K is outside 1700-12000"):
        check_light(OmegaConf.merge(compose_cfg().light, {"temperature": 500}))


def test_a_failed_lamp_share_of_half_turns_off_half_the_lamps():
    lights = built("light.coverage=0.5")[0].lights
    on = sum(1 for light in lights if light.intensity > 0)
    assert on == round(0.5 * len(lights)) and len(lights) > 10


def test_intensity_scales_every_lit_lamp():
    weak = max(light.intensity for light in built("light.intensity=0.5")[0].lights)
    strong = max(light.intensity for light in built("light.intensity=2.5")[0].lights)
    assert strong == pytest.approx(5 * weak)


# -- the floor ----------------------------------------------------------------------------------------------------

def floor_params(scene) -> dict:
    """The dressed lane floor's texture parameters (wetness, grime) and the markings' wear."""
    for e in scene.entities:
        for shape in e.shapes:
            tex = getattr(getattr(shape, "material", None), "texture", None)
            if tex is not None and tex.kind == "asphalt":
                return dict(tex.params)
    raise AssertionError("no asphalt floor")


@pytest.mark.parametrize("key", ["wetness", "grime"])
def test_floor_wetness_and_grime(key):
    dry = floor_params(built(f"materials.{key}=0.0")[0])
    wet = floor_params(built(f"materials.{key}=0.9")[0])
    assert wet[key] > dry[key]


def test_marking_wear_fades_the_paint():
    def paint(scene):
        return [s.material for e in scene.by_role("marking") for s in e.shapes if hasattr(s, "material")]

    fresh, worn = paint(built("modifiers.wear.wear=0.0")[0]), paint(built("modifiers.wear.wear=0.9")[0])
    assert fresh != worn


# -- the sensor ---------------------------------------------------------------------------------------------------

def sensor_mean(**params) -> float:
    from garage_exp.perception.sensor import make_sensor

    base = dict(compose_cfg().sensor.params)  # the default camera (look=real)
    frame = np.full((48, 64, 3), 100, np.uint8)  # the AE reaches its target within its gain either way
    out = make_sensor(name="camera", kind="camera", params={**base, **params}).apply(frame, np.random.default_rng(0))
    return float(out.mean())


def test_exposure_bias_brightens_and_darkens_the_frame():
    assert sensor_mean(exposure_bias=1.0) > sensor_mean(exposure_bias=0.0) > sensor_mean(exposure_bias=-1.0)


def test_gain_and_read_noise_of_the_sensor():
    from garage_exp.perception.sensor import make_sensor

    base = dict(compose_cfg().sensor.params)
    frame = np.full((48, 64, 3), 8, np.uint8)  # very dark: the gain cap binds

    def out(**params):
        return make_sensor(name="camera", kind="camera", params={**base, "blur_sigma": 0.0, **params}).apply(
            frame, np.random.default_rng(0)).astype(float)

    assert out(max_gain=16.0).mean() > out(max_gain=2.0).mean()
    assert out(read_noise=5.0, exposure=0.05).std() > out(read_noise=0.5, exposure=0.05).std()


def test_exposure_bias_out_of_range_is_refused():
    with pytest.raises(GarageError, match="exposure_bias must be in -4..4 EV"):
        sensor_mean(exposure_bias=6.0)


# -- the space ----------------------------------------------------------------------------------------------------

def test_the_wide_space_has_twenty_or_more_factors_most_of_them_continuous():
    from garage_exp.search import space as space_mod

    cfg = compose_cfg("space=wide")
    space = space_mod.build(space_mod.expand(cfg, ["space=wide"]), cfg, {})
    continuous = [k for k, d in space.params.items() if not hasattr(d, "choices")]
    assert len(space.params) >= 20 and len(continuous) > len(space.params) / 2
    assert cfg.case.name == "oneshot" and cfg.case.motion.actor == ""  # drawn on the one-shot case
    assert OmegaConf.to_container(cfg.space.require) == {"min_visible": 0.3, "min_box": 25.0, "max_distance": 30.0,
                                                         "max_truncation": 0.5}
    assert compose_cfg().space.params == []  # no space unless asked


def test_every_drawn_key_is_one_the_config_has():
    """Each space entry's key exists in the composed config (else the search refuses it: space.build), composed
    with the levels the space itself picks (plan=generated)."""
    from garage_exp.search import space as space_mod

    cfg = compose_cfg("space=wide", "plan=generated")
    for entry in cfg.space.params:
        key = entry.split("=", 1)[0]
        assert key in ("camera.mount",) or OmegaConf.select(cfg, key, default="absent") != "absent", key


def test_a_command_line_override_of_a_space_key_wins():
    from garage_exp.search import space as space_mod

    cfg = compose_cfg("space=wide")
    args = space_mod.expand(cfg, ["space=wide", "light.temperature=interval(4000,5000)", "seed=3"])
    assert [a for a in args if a.startswith("light.temperature=")] == ["light.temperature=interval(4000,5000)"]
    assert args[-3:] == ["space=wide", "light.temperature=interval(4000,5000)", "seed=3"]  # the command's last
    assert "light.coverage=interval(0.4,1.0)" in args
    assert space_mod.expand(compose_cfg(), ["seed=3"]) == ["seed=3"]  # no space: the command as written


def test_a_case_on_the_command_line_wins_over_the_spaces():
    assert compose_cfg("space=wide", "case='1'").case.name == "1"


def test_a_space_setting_a_key_twice_is_refused_naming_the_entry():
    from garage_exp.search import space as space_mod

    cfg = compose_cfg("space=wide")
    cfg.space.params.append("light.seed=3")
    with pytest.raises(GarageError, match=r"space.params\[\d+\]: 'light.seed=3': light.seed is set twice"):
        space_mod.expand(cfg, [])


def test_a_lamp_colour_is_the_black_body_at_its_temperature():
    from garage_exp.scene.lamps import kelvin_rgb

    reds = [kelvin_rgb(t)[2] / kelvin_rgb(t)[0] for t in (1700, 2000, 3000, 4000, 5000, 6500)]
    assert reds == sorted(reds)  # bluer as it gets hotter
    assert max(kelvin_rgb(12000)) == 1.0 and kelvin_rgb(12000)[2] == 1.0  # past daylight: blue-white
    assert math.isclose(kelvin_rgb(4000)[1], 0.65, abs_tol=0.05)  # a 4000 K LED: warm white


def test_the_occluder_faces_along_the_lane_whatever_the_target_does():
    _, _, s = shot("case.actors.target.yaw=60", "case.actors.occluder.type=van_silver",
                   "case.actors.occluder.offset=2.5")
    assert s.poses["occluder"].yaw == pytest.approx(s.ego.yaw % 360)


def test_the_loop_reads_a_shipped_space_as_the_search_does():
    """`python -m garage_exp.loop space=wide`: its searches get `space=wide` on their command line (the space's
    requirements, cells and case come with it), and its held-out sample draws the same keys (loop/heldout.py:
    space_params); `space.params=[...]` replaces the file's list."""
    from conftest import compose_cfg as compose
    from garage_exp.loop.heldout import space_params
    from garage_exp.loop.schema import searched as loop_searched
    from garage_exp.search import space as space_mod

    from garage_exp.loop.schema import space_by_name

    assert loop_searched(compose(*space_by_name(["space=wide"]), config="loop")) == ["space=wide"]
    assert loop_searched(compose(config="loop")) == ["space=loop"]
    assert loop_searched(compose("space.params=['light=dim']", config="loop")) == ["light=dim"]

    cfg = compose_cfg("space=wide")
    searched = space_mod.build(space_mod.expand(cfg, ["space=wide", "seed=int(interval(0,9))"]), cfg, {}).params
    held = space_params(["space=wide", "seed=int(interval(0,9))"])
    assert list(held) == list(searched) and "light.temperature" in held and "seed" in held


@pytest.mark.render
def test_the_renderer_paints_the_target_and_the_paint_does_not_stay_on_its_model():
    """One frame each at 160x120 through the ideal sensor: hue 0 paints the target red, hue 240 blue; the same model
    unpainted afterwards in the same warm renderer is grey again (SAPIEN caches a model's file, not its paint)."""
    from conftest import require

    from garage_exp.core.plugins import build as build_plugin
    from garage_exp.render.open import open_renderer
    from garage_exp.scenario.assemble import HIDDEN
    from garage_exp.run.pipeline import render_frames
    from garage_exp.run.preflight import preflight

    require("vulkan", "vehicles")

    def colour(*paint):
        cfg = compose_cfg(*BASE, "case.actors.target.type=tcamrysilver", "case.actors.target.distance=7",
                          "case.actors.occluder.offset=3.5", "sensor=ideal", "camera.width=160", "camera.height=120",
                          *paint)
        job = preflight(cfg, check_space=False, load=False)
        renderer = open_renderer(cfg.renderer, HIDDEN)
        renderer.load(job.scene)
        (item,) = render_frames(cfg, job.scene, job.setup.shots, renderer,
                                build_plugin(cfg.sensor, "a sensor model", "sensor._target_"), np.random.default_rng(0))
        x1, y1, x2, y2 = item.target.visible_box
        return item.rgb[y1:y2, x1:x2].reshape(-1, 3).astype(float).mean(axis=0)

    red = colour("case.actors.target.hue=0", "case.actors.target.saturation=0.8")
    blue = colour("case.actors.target.hue=240", "case.actors.target.saturation=0.8")
    own = colour()
    assert red[0] > red[2] + 20 and blue[2] > blue[0] + 20
    assert abs(own[0] - own[2]) < 15  # the silver model's own paint: neither red nor blue
