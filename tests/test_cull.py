"""Frustum culling (render/cull.py, sapien_backend): what a frame hides is provably out of view, and hiding it
changes no pixel, no id and no ground truth. The geometry is checked without a device; the render check uses a
real job's first frames on the research plan with palette=busy (parked cars in and out of view)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import ROOT, compose_cfg, require

from garage_exp.render.cull import box_corners, frustum_planes, outside_frustum
from garage_exp.scene.camera import camera_to_world, to_camera
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import CameraSpec, Pose
from garage_exp.run.spec import scene_spec

SPEC = CameraSpec("front", Pose(0.0, 0.0, 1.5), width=640, height=480, fovy=60.0, near=0.05, far=100.0)
CAM = camera_to_world(Pose(), SPEC)  # at (0, 0, 1.5) looking along +x


def outside(lo, hi) -> bool:
    return bool(outside_frustum(frustum_planes(CAM, SPEC), np.array([lo], float), np.array([hi], float))[0])


def covers_no_pixel(lo, hi, spec: CameraSpec = SPEC, cam: np.ndarray = CAM, samples: int = 9) -> bool:
    """No point of the box (a grid of samples through its volume) lands in the image in front of the near
    plane and before the far plane."""
    axes = [np.linspace(lo[k], hi[k], samples) for k in range(3)]
    points = np.stack(np.meshgrid(*axes), axis=-1).reshape(-1, 3)
    local = to_camera(cam, points)
    ahead = (local[:, 0] >= spec.near) & (local[:, 0] <= spec.far)
    u, v = lens_of(spec).pixels(local[ahead])
    return not np.any((u >= 0) & (u <= spec.width) & (v >= 0) & (v <= spec.height))


@pytest.mark.parametrize("lo, hi, expected", [
    ((9.0, -1.0, 0.0), (11.0, 1.0, 1.5), False),      # a car ahead
    ((-6.0, -1.0, 0.0), (-4.0, 1.0, 1.5), True),      # behind the camera
    ((101.0, -1.0, 0.0), (104.0, 1.0, 1.5), True),    # beyond the far plane
    ((99.0, -1.0, 0.0), (104.0, 1.0, 1.5), False),    # straddles the far plane: kept
    ((5.0, 6.0, 0.0), (7.0, 8.0, 1.5), True),         # left of the 75-degree horizontal view at 5-7 m
    ((5.0, 3.0, 0.0), (7.0, 8.0, 1.5), False),        # reaches into it
    ((-50.0, -50.0, -0.2), (50.0, 50.0, 0.0), False),  # the floor under the camera
    ((2.0, -1.0, -5.0), (3.0, 1.0, -2.0), True),      # below the view at 2-3 m (vertical FOV 60 degrees)
])
def test_frustum_keeps_what_reaches_the_view_and_hides_what_does_not(lo, hi, expected):
    assert outside(lo, hi) is expected
    if expected:
        assert covers_no_pixel(lo, hi)


def test_every_box_it_hides_covers_no_pixel_from_any_pose():
    """Random boxes and camera poses (yaw, pitch): a hidden box has no point in the image (the converse, that
    boxes in view are kept, is what the pixel comparison below shows)."""
    rng = np.random.default_rng(3)
    hidden = 0
    for _ in range(300):
        spec = replace(SPEC, pitch=float(rng.uniform(-20, 20)), fovy=float(rng.uniform(40, 90)),
                       far=float(rng.uniform(20, 100)))
        cam = camera_to_world(Pose(*rng.uniform(-10, 10, 2), 0.0, float(rng.uniform(0, 360))), spec)
        lo = rng.uniform(-40, 40, 3)
        hi = lo + rng.uniform(0.1, 6.0, 3)
        if outside_frustum(frustum_planes(cam, spec), lo[None], hi[None])[0]:
            hidden += 1
            assert covers_no_pixel(lo, hi, spec, cam), (lo, hi)
    assert hidden > 100  # the check is not vacuous


def test_corners_of_a_box():
    corners = box_corners(np.zeros(3), np.array([1.0, 2.0, 3.0]))
    assert corners.shape == (8, 3) and corners.min(axis=0).tolist() == [0, 0, 0]
    assert corners.max(axis=0).tolist() == [1, 2, 3]


@pytest.mark.render
@pytest.mark.slow
def test_culled_frames_equal_unculled_ones_pixel_for_pixel():
    """Three frames of case 1 on the research plan with palette=busy, rendered with culling on and off: colour,
    ids and ground truth are identical (tolerance: none), and every body the culled frame hid has no AABB
    corner in the image."""
    require("vulkan", "vehicles")
    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.scenario.assemble import build_scene
    from garage_exp.run.pipeline import render_frames
    from garage_exp.plan import classify, load_plan
    from garage_exp.render.sapien_backend import get_renderer
    from garage_exp.core.plugins import build

    cfg = compose_cfg("palette=busy", "case=1")
    classified = classify(load_plan(ROOT / "plans" / "research.yaml"))
    scene, setup = build_scene(scene_spec(cfg), classified, VehicleLibrary(), np.random.default_rng(cfg.seed))
    setup = replace(setup, shots=setup.shots[::30][:3])
    renderer = get_renderer(max_lights=cfg.renderer.max_lights)
    renderer.load(scene)
    frames, hidden = {}, []
    try:
        for cull in (True, False):
            renderer.cull = cull
            frames[cull] = list(render_frames(cfg, scene, setup.shots, renderer, build(cfg.sensor, "a sensor model", "sensor._target_"),
                                              np.random.default_rng(1)))
            if cull:
                for shot in setup.shots:  # re-render each shot culled to see what it hid
                    renderer.set_pose("ego", shot.ego)
                    renderer.render(scene.cameras[0].name)
                    rows = np.flatnonzero(renderer.bodies.base & ~renderer.bodies.shown)
                    # the boxes as they stood then: an actor (and its shadow decal) moves on in later frames
                    hidden.append((renderer.camera_pose(scene.cameras[0].name), rows,
                                   renderer.bodies.lo[rows].copy(), renderer.bodies.hi[rows].copy()))
    finally:
        renderer.cull = True
    assert len(frames[True]) == 3
    for a, b in zip(frames[True], frames[False]):
        assert np.array_equal(a.rgb, b.rgb)
        assert a.truth == b.truth and a.truth
    spec = scene.cameras[0]
    assert all(len(rows) > 20 for _, rows, _, _ in hidden)  # most of the garage is out of view each time
    for pose, rows, lo, hi in hidden:
        for k in range(len(rows)):
            assert covers_no_pixel(lo[k], hi[k], spec, pose, samples=3)


# ---- the renderer's parts that need no device (issue 32, item 5: split out of sapien_backend) ----------------


def test_silhouette_groups_share_a_render_only_when_their_rectangles_are_disjoint():
    from garage_exp.render.silhouettes import disjoint_groups, image_rect

    ahead = image_rect(np.array([[9.0, -1.0, 0.0], [11.0, 1.0, 1.5]]), CAM, SPEC)
    assert ahead is not None and 0 < ahead[0] < ahead[2] < SPEC.width
    assert image_rect(np.array([[-6.0, -1.0, 0.0], [-4.0, 1.0, 1.5]]), CAM, SPEC) is None  # behind
    assert image_rect(np.array([[-1.0, -1.0, 0.0], [1.0, 1.0, 2.0]]), CAM, SPEC) == (0.0, 0.0, 640.0, 480.0)
    rects = {"a": (0, 0, 10, 10), "b": (20, 0, 30, 10), "c": (5, 5, 25, 15), "d": (40, 40, 50, 50)}
    assert disjoint_groups(rects) == [["a", "b", "d"], ["c"]]


def test_the_light_pool_goes_to_the_strongest_lamps_at_the_camera():
    from garage_exp.render.light_pool import LAMP_POWER, LightPool
    from garage_exp.scene.description import Light, Scene

    lamps = [Light(f"l{k}", (3.0 * k, 0.0, 2.5)) for k in range(5)] + [Light("off", (0.0, 0.0, 2.5), intensity=0.0)]
    pool = LightPool()
    pool.set_lamps(Scene("s", lights=lamps))
    assert len(pool.pos) == 5 and pool.rgb[0] == pytest.approx(np.array(lamps[0].color) * LAMP_POWER)
    assert list(pool.choose([6.2, 0.0, 1.5], 3)) == [2, 3, 1]  # nearest first; the dark lamp takes none
    assert len(pool.choose([0.0, 0.0, 1.5], 10)) == 5


def test_a_shape_type_without_a_sapien_converter_is_one_line_error():
    from garage_exp.core.errors import GarageError
    from garage_exp.render.sapien_builder import sapien_shape

    with pytest.raises(GarageError, match="cannot draw a str"):
        sapien_shape("not a shape", None, "car", Pose())
