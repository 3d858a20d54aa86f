"""Fisheye cameras (issue 11): OpenCV's lens model, the cube map it is rendered from, and ground truth on the
remapped frames. The model tests need no renderer; the render tests use test_render's small hall at 160x120."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from test_render import garage, renderer, save, target_truth  # noqa: F401 - renderer is a fixture

from garage_exp.render.fisheye import cube_map, view_remap
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.description import Box, CameraSpec, Entity, Material, Pose
from garage_exp.scene.lenses import Cylindrical, Fisheye, Pinhole

EQUISOLID = (-0.0417, 0.0005, 0.0, 0.0)  # conf/camera/fisheye4.yaml's lens
W, H = 160, 120
WHITE = Material("paint", (0.9, 0.9, 0.9, 1.0))
GREEN = Material("green", (0.1, 0.7, 0.1, 1.0), roughness=0.4)


def directions(n: int, max_angle: float, seed: int = 0) -> np.ndarray:
    """n unit rays (SAPIEN axes) at most max_angle degrees from the optical axis."""
    rng = np.random.default_rng(seed)
    theta = np.radians(rng.uniform(0.0, max_angle, n))
    phi = rng.uniform(0.0, 2 * np.pi, n)
    return np.stack([np.cos(theta), np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi)], axis=1)


def test_the_lens_is_opencvs_fisheye_within_90_degrees():
    lens = Fisheye(640, 480, 190.0, EQUISOLID)
    d = directions(200, 85.0)
    u, v = lens.project(d)
    opencv = np.stack([-d[:, 1], -d[:, 2], d[:, 0]], axis=1)[None]  # OpenCV's axes: x right, y down, z forward
    opencv_k = lens.K - np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0]])  # OpenCV: pixel centres at integers
    points, _ = cv2.fisheye.projectPoints(opencv, np.zeros(3), np.zeros(3), opencv_k, np.array(lens.k))
    assert np.abs(points[0] - np.stack([u - 0.5, v - 0.5], axis=1)).max() < 1e-6
    # the lens's field spans the image width, and rays round-trip through the pixels
    assert lens.project(np.array([[0.0, 1.0, 0.0]]))[0][0] == pytest.approx(
        320 - lens.f * float(lens.distort(np.array(math.pi / 2))))
    rays, inside = lens.rays()
    uu, vv = lens.project(rays[inside])
    grid_u, grid_v = np.meshgrid(np.arange(640) + 0.5, np.arange(480) + 0.5)
    assert np.abs(uu - grid_u[inside]).max() < 1e-6 and np.abs(vv - grid_v[inside]).max() < 1e-6
    assert inside[240, 1] and inside[240, 638] and not inside[0, 0]  # the circle spans the width


def test_the_cube_map_renders_only_the_faces_the_lens_sees_at_the_size_it_needs():
    wide = cube_map(Fisheye(640, 480, 190.0, EQUISOLID))
    assert wide.faces == ["front", "left", "right", "up", "down"]  # 95 degrees off axis never reaches the back
    narrow = cube_map(Fisheye(640, 480, 80.0, (0.0, 0.0, 0.0, 0.0)))
    assert narrow.faces == ["front"]
    half = cube_map(Fisheye(320, 240, 190.0, EQUISOLID))
    for a, b in zip(wide.sizes, half.sizes):
        assert b - 2 == pytest.approx((a - 2) / 2, abs=2)  # face size follows the image size
    # not higher than needed: a face pixel at the image centre is no smaller than 0.9 of a fisheye pixel there
    lens = Fisheye(640, 480, 190.0, EQUISOLID)
    front = wide.sizes[0] - 2
    assert (front / 2) / lens.f < 1.6  # face focal / fisheye focal (the rim needs denser faces than the centre)
    assert (front / 2) / lens.f > 0.9
    # of each face only the rectangle the lens samples: the 4:3 image cuts the circle, so up and down are bands
    up = wide.crops[wide.faces.index("up")]
    assert up[3] < 0.6 * wide.sizes[wide.faces.index("up")]
    assert wide.rendered_pixels < 0.7 * sum(n * n for n in wide.sizes)
    assert narrow.rendered_pixels < narrow.sizes[0] ** 2  # an 80-degree lens needs the front face's middle


def test_views_undistorted_from_a_fisheye_keep_straight_lines_straight():
    lens = Fisheye(320, 240, 190.0, EQUISOLID)
    for view in (Pinhole.from_fovx(320, 240, 120.0), Cylindrical.from_fovx(320, 240, 180.0)):
        map_x, map_y, flat = view_remap(lens, view)
        assert (flat >= 0).mean() > 0.9
        rays, _ = view.rays()
        u, v = lens.project(rays)
        assert np.allclose(map_x[flat >= 0], (u - 0.5)[flat >= 0], atol=1e-3)
    # a vertical 3D line 1.5 m ahead, 2 m left: straight in both views, curved in the fisheye
    line = np.stack([np.full(9, 1.5), np.full(9, 2.0), np.linspace(-2.0, 2.0, 9)], axis=1)
    assert np.ptp(Pinhole.from_fovx(320, 240, 120.0).project(line)[0]) < 1e-9
    assert np.ptp(Cylindrical.from_fovx(320, 240, 180.0).project(line)[0]) < 1e-9
    assert np.ptp(lens.project(line)[0]) > 10.0


def fisheye_camera(pitch: float = 0.0, view: str = "raw", mount: Pose = Pose(0.5, 0.0, 1.6)) -> CameraSpec:
    return CameraSpec("front", mount, pitch=pitch, width=W, height=H, model="fisheye", fov=190.0,
                      k=EQUISOLID, view=view)


@pytest.mark.render
def test_scene_points_land_where_the_lens_model_puts_them(renderer):  # noqa: F811
    cam = fisheye_camera(pitch=10.0)
    scene = garage(camera=cam, target_at=30.0)
    pose = camera_to_world(scene.entity("ego").pose, cam)
    # small boxes on the axis, off to the sides and beyond 90 degrees (behind the lens's plane)
    probes = {"ahead": (4.0, 0.0, 0.0), "left": (2.0, 2.5, 0.3), "right_low": (2.0, -2.0, -0.8),
              "up_left": (1.5, 1.0, 1.0), "behind_left": (-0.05, 2.0, -0.3)}
    for name, local in probes.items():
        centre = pose[:3, :3] @ np.array(local) + pose[:3, 3]
        scene.entities.append(Entity(name, "moving", Pose(*centre), [Box((0.12, 0.12, 0.12), GREEN)],
                                     static=False))
    renderer.load(scene)
    frame = renderer.render("front")
    save(frame, "test_fisheye_probes")
    assert frame.lens is not None and frame.rgb.shape == (H, W, 3)
    for name in probes:
        centre = scene.entity(name).pose
        uv, _ = frame.project(np.array([[centre.x, centre.y, centre.z]]))
        rows, cols = np.nonzero(frame.ids == renderer.ids[name])
        assert len(rows) >= 2, name
        assert (cols.mean() + 0.5, rows.mean() + 0.5) == pytest.approx(tuple(uv[0]), abs=1.0), name


@pytest.mark.render
def test_a_straight_lane_line_is_curved_as_the_model_predicts(renderer):  # noqa: F811
    # On the ego's nose (its body would hide the line's near end), looking down as bumper cameras do: a line
    # parallel to the optical axis would lie in a plane through it and stay straight.
    cam = fisheye_camera(pitch=20.0, mount=Pose(2.3, 0.0, 0.6))
    scene = garage(camera=cam, target_at=30.0)
    # a lane line on the floor 1.5 m left of the camera, from 1.3 m behind it to 25 m ahead
    scene.entities.append(Entity("line", "moving", Pose(14.0, 1.5, 0.005), [Box((26.0, 0.12, 0.01), WHITE)],
                                 static=False))
    renderer.load(scene)
    frame = renderer.render("front")
    save(frame, "test_fisheye_line")
    rows, cols = np.nonzero(frame.ids == renderer.ids["line"])
    assert len(rows) > 50
    # the model's curve: the line's centre points projected through the lens
    xs = np.linspace(1.0, 27.0, 4000)
    uv, _ = frame.project(np.stack([xs, np.full_like(xs, 1.5), np.full_like(xs, 0.005)], axis=1))
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    curve = uv[inside]
    # row by row, the line's pixels centre on the curve: within a pixel (one-pixel-wide rows quantise to +-0.5)
    assert np.all(np.diff(curve[:, 1]) < 0)  # farther along the line is higher in the image
    centres = [(cols[rows == r].mean() + 0.5, r + 0.5) for r in np.unique(rows)]
    u_at = np.interp([v for _, v in centres], curve[::-1, 1], curve[::-1, 0])
    error = np.abs(np.array([u for u, _ in centres]) - u_at)
    assert np.percentile(error, 95) < 1.0 and error.max() < 1.5 and error.mean() < 0.5
    # and the curve is not straight: its middle sags many pixels from the chord between its ends
    a, b = curve[0], curve[-1]
    chord = (b - a) / np.linalg.norm(b - a)
    sag = np.abs(chord[0] * (curve[:, 1] - a[1]) - chord[1] * (curve[:, 0] - a[0]))
    assert sag.max() > 5.0


@pytest.mark.render
@pytest.mark.parametrize("view", ["raw", "perspective", "cylindrical"])
def test_ground_truth_holds_on_fisheye_frames(renderer, view):  # noqa: F811
    cam = fisheye_camera(view=view)
    scene = garage(camera=cam, target_at=9.0)
    renderer.load(scene)
    frame, clear = target_truth(renderer, scene)
    assert clear is not None and clear.visible_fraction == pytest.approx(1.0, abs=0.01)
    # the silhouette (unlit renders of the faces, remapped) is the target's pixels of the lit frame
    silhouette = renderer.unoccluded_ids("front", ["target"])["target"]
    assert np.array_equal(silhouette, frame.ids == renderer.ids["target"])
    # the full box hugs the lens's projection of the target's 3D box
    from garage_exp.perception.groundtruth import _edge_points, world_corners

    corners = world_corners(scene.entity("target"), scene.entity("target").pose)
    uv, _ = frame.project(_edge_points(corners))
    x1, y1, x2, y2 = clear.full_box
    assert (x1, y1, x2, y2) == pytest.approx((uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()),
                                             abs=2.5)
    scene = garage(camera=cam, target_at=9.0, pillar_at=5.0)
    renderer.load(scene)
    frame, hidden = target_truth(renderer, scene)
    save(frame, f"test_fisheye_pillar_{view}")
    assert hidden is not None and 0.0 < hidden.visible_fraction < 0.9
    assert hidden.full_box == clear.full_box and hidden.unoccluded_pixels == clear.unoccluded_pixels


@pytest.mark.render
def test_a_fisheye_scene_reloaded_with_other_actors_renders_as_a_fresh_load(renderer):  # noqa: F811
    """A search's trials replace only the actors: every cube face camera goes and comes back, and the frame
    is a fresh load's."""
    from garage_exp.render.sapien_backend import SapienRenderer

    renderer.load(garage(camera=fisheye_camera(), target_at=12.0))
    renderer.render("front")
    sapien_scene, entities = renderer.sapien_scene, len(renderer.sapien_scene.get_entities())
    scene = garage(camera=fisheye_camera(), target_at=7.0)
    renderer.load(scene)
    assert renderer.sapien_scene is sapien_scene  # the statics stayed
    assert len(renderer.sapien_scene.get_entities()) == entities  # and no face camera was left behind
    reused = renderer.render("front")
    fresh_renderer = SapienRenderer(max_lights=8)
    fresh_renderer.load(scene)
    assert np.array_equal(reused.rgb, fresh_renderer.render("front").rgb)
