"""The bird's-eye view from the fisheye4 rig (issue 25): a floor point lands where the rig says, within a pixel;
the stitched picture takes each pixel from one camera; the maps are cached per (rig, spec). No renderer."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import compose_cfg

from garage_exp.render.bev import BevSpec, bev_maps, check_bev
from garage_exp.scene.camera import camera_to_world, rig_specs, to_camera
from garage_exp.scene.description import Pose
from garage_exp.scene.lenses import lens_of

EGO_EXTENT = (4.77, 1.96, 1.50)  # the default ego (tcamrysilver)
EGO = Pose(12.3, -4.1, 0.0, 57.0)  # anywhere, at any heading: the maps live in the ego's frame
SPEC = BevSpec(10.0, 10.0, 0.02)


@pytest.fixture(scope="module")
def rig():
    return rig_specs(compose_cfg("camera=fisheye4").camera, EGO_EXTENT)


def floor_points(n: int = 60, seed: int = 0) -> np.ndarray:
    """World floor points 1.5-4.8 m from the ego's centre in every direction, inside the BEV."""
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, 2 * math.pi, n)
    r = rng.uniform(1.5, 4.8, n)
    ex, ey = r * np.cos(ang), r * np.sin(ang)
    keep = (np.abs(ex) < 4.9) & (np.abs(ey) < 4.9) & ~((np.abs(ex) < 2.5) & (np.abs(ey) < 1.1))
    world = [EGO.compose(Pose(x, y)) for x, y in zip(ex[keep], ey[keep])]
    return np.array([[p.x, p.y, 0.0] for p in world])


def camera_pixels(cam, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the camera images world points, through the renderer's own pose and lens, and whether it sees them."""
    local = to_camera(camera_to_world(EGO, cam), points)
    lens = lens_of(cam)
    u, v = lens.project(local)
    theta = np.arctan2(np.hypot(local[:, 1], local[:, 2]), local[:, 0])
    seen = (theta <= lens.theta_max) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    return np.stack([u, v], axis=1), seen


def test_a_floor_point_lands_in_the_bev_within_a_pixel_of_where_the_spec_says(rig):
    maps = bev_maps(rig, SPEC, EGO_EXTENT)
    points = floor_points()
    want = SPEC.world_to_pixel(EGO, points)
    checked = {c.name: 0 for c in rig}
    worst = {c.name: 0.0 for c in rig}
    for k, cam in enumerate(rig):
        pix, seen = camera_pixels(cam, points)
        for p, w in zip(pix[seen], want[seen]):
            # the BEV pixel whose sample in this camera is nearest the point's image
            d = np.hypot(maps.map_x[k] - (p[0] - 0.5), maps.map_y[k] - (p[1] - 0.5))
            row, col = np.unravel_index(np.argmin(d), d.shape)
            assert d[row, col] < 3.0  # near a lens a BEV pixel spans a few of its pixels
            # where between BEV pixels the map reaches the point's image: the map's local linear inverse
            mx, my = maps.map_x[k], maps.map_y[k]
            jac = np.array([[mx[row, col + 1] - mx[row, col], mx[row + 1, col] - mx[row, col]],
                            [my[row, col + 1] - my[row, col], my[row + 1, col] - my[row, col]]], float)
            step = np.linalg.solve(jac, [p[0] - 0.5 - mx[row, col], p[1] - 0.5 - my[row, col]])
            found = (col + 0.5 + step[0], row + 0.5 + step[1])
            miss = math.hypot(found[0] - w[0], found[1] - w[1])
            assert miss <= 1.0, (cam.name, p, w, found)
            worst[cam.name] = max(worst[cam.name], miss)
            checked[cam.name] += 1
    assert min(checked.values()) >= 5, checked  # every camera sees several of the points
    assert max(worst.values()) < 0.1, worst  # in fact a hundredth of a pixel: the same lens, the same pose


def test_a_mark_on_each_fisheye_picture_shows_at_its_floor_point_in_the_stitched_bev(rig):
    maps = bev_maps(rig, SPEC, EGO_EXTENT)
    points = floor_points(200, seed=1)
    want = SPEC.world_to_pixel(EGO, points)
    cols, rows = want[:, 0].astype(int), want[:, 1].astype(int)
    for k, cam in enumerate(rig):
        pix, seen = camera_pixels(cam, points)
        mine = seen & (maps.owner[rows, cols] == k)  # points the BEV takes from this camera
        assert mine.sum() >= 3, cam.name
        for p, w in list(zip(pix[mine], want[mine]))[:3]:
            pictures = {c.name: np.zeros((c.height, c.width), np.float32) for c in rig}
            pictures[cam.name][int(p[1]), int(p[0])] = 1.0  # the fisheye pixel that images the point
            bev = maps.stitch(pictures)
            assert bev.max() > 0
            r, c = np.nonzero(bev)
            weight = bev[r, c]
            centre = np.average(c + 0.5, weights=weight), np.average(r + 0.5, weights=weight)
            # a fisheye pixel covers up to a few BEV pixels: its footprint's centre is the point's, within one
            assert math.hypot(centre[0] - w[0], centre[1] - w[1]) <= 1.0 + 0.5 * math.hypot(
                *(np.ptp(c), np.ptp(r))), (cam.name, centre, w)


def test_each_camera_owns_its_side_of_the_ego_and_the_seams_lie_between(rig):
    maps = bev_maps(rig, SPEC, EGO_EXTENT)
    h, w = maps.owner.shape
    names = maps.cameras
    assert names[maps.owner[10, w // 2]] == "front" and names[maps.owner[h - 10, w // 2]] == "rear"
    assert names[maps.owner[h // 2, 10]] == "left" and names[maps.owner[h // 2, w - 10]] == "right"
    assert maps.owner[h // 2, w // 2] == -1  # under the ego's body
    seams = maps.seams
    assert seams.any() and not seams[maps.owner == -1].any()
    o = maps.owner
    change = o[:, 1:] != o[:, :-1]
    pairs = {frozenset((names[a], names[b])) for a, b in zip(o[:, 1:][change], o[:, :-1][change]) if a >= 0 and b >= 0}
    assert pairs == {frozenset(p) for p in (("front", "left"), ("front", "right"), ("rear", "left"), ("rear", "right"))}


def test_the_maps_are_cached_per_rig_and_spec(rig):
    a = bev_maps(rig, SPEC, EGO_EXTENT)
    assert bev_maps(list(rig), BevSpec(10.0, 10.0, 0.02), EGO_EXTENT) is a
    assert bev_maps(rig, BevSpec(10.0, 10.0, 0.05), EGO_EXTENT) is not a
    assert bev_maps(rig[:2], SPEC, EGO_EXTENT) is not a
    assert a.owner.shape == (500, 500) and not a.owner.flags.writeable


def test_the_bev_spec_is_checked():
    from garage_exp.core.errors import GarageError

    check_bev(BevSpec())
    with pytest.raises(GarageError, match="camera.bev.meters_per_pixel"):
        check_bev(BevSpec(meters_per_pixel=0.001))
    with pytest.raises(GarageError, match="camera.bev.meters_per_pixel"):
        check_bev(BevSpec(length=60.0, width=60.0, meters_per_pixel=0.02))


def test_the_camera_bev_node_is_the_bev_spec():
    """One class for the `camera.bev` node and the extent the BEV code uses (no Conf/Spec pair): a composed node
    typed as it is the spec, equal (and cached, bev_maps) by its extent whether or not it is enabled."""
    from omegaconf import OmegaConf

    from garage_exp.render.bev import spec_of

    node = OmegaConf.merge(OmegaConf.structured(BevSpec), {"enabled": True, "length": 10, "meters_per_pixel": 0.02})
    assert OmegaConf.get_type(node) is BevSpec
    spec = spec_of(node)
    assert spec == BevSpec(10.0, 18.0, 0.02) and spec.enabled and hash(spec) == hash(BevSpec(10.0, 18.0, 0.02))
    assert spec.size == (900, 500)
