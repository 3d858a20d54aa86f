"""Named mounts and the camera group's top-level factors (issue 11): plain overrides of a one-camera rig, poses
scaled by the ego's extent, `camera=front` exactly as before, and the ego's body seen only where a real camera
at the mount would see it (rays cast at the default ego's mesh, no renderer)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import compose_cfg, require

from garage_exp.core.errors import GarageError
from garage_exp.scene.camera import FOVY_LEVELS, MOUNTS, camera_to_world, check_camera, mount_pose, rig_specs
from garage_exp.scene.description import CameraSpec, Pose

CAMRY = (4.7727, 1.9558, 1.499)


def rig(*overrides: str):
    return compose_cfg(*overrides).camera


def test_front_rig_is_the_camera_it_always_was():
    (spec,) = rig_specs(rig(), CAMRY)
    assert spec == CameraSpec("front", Pose(0.3, 0.0, CAMRY[2] + 0.05, 0.0), pitch=0.0, fovy=60.0, width=640,
                              height=480)


def test_mount_and_fovy_are_plain_overrides():
    (spec,) = rig_specs(rig("camera.mount=mirror", "camera.fovy=90", "camera.pitch=5", "camera.z=0.1"), CAMRY)
    base = mount_pose("mirror", CAMRY)
    assert spec.mount == Pose(base.x, base.y, pytest.approx(base.z + 0.1), 0.0)
    assert (spec.fovy, spec.pitch, spec.width, spec.height) == (90.0, 5.0, 640, 480)
    (wide,) = rig_specs(rig("camera.mount=rear", "camera.width=320", "camera.height=240"), CAMRY)
    assert wide.mount.yaw == 180.0 and wide.mount.x < -CAMRY[0] / 2 and (wide.width, wide.height) == (320, 240)
    assert FOVY_LEVELS == (30.0, 60.0, 90.0, 120.0)


def test_mounts_scale_with_the_ego():
    small, large = (3.6, 1.6, 1.4), (5.4, 2.0, 1.9)
    for name in MOUNTS:
        a, b = mount_pose(name, small), mount_pose(name, large)
        assert a.yaw == b.yaw
        if name in ("bumper", "rear"):
            assert abs(a.x) == pytest.approx(1.83) and abs(b.x) == pytest.approx(2.73)
        assert b.z > a.z


@pytest.mark.parametrize("overrides, key, words", [
    (["camera.mount=dashboard"], "camera.mount", "unknown mount 'dashboard'"),
    (["camera.fovy=171"], "camera.fovy", "outside 1-170"),
    (["camera=surround", "camera.fovy=90"], "camera.fovy", "one-camera rig"),
    (["camera.view=fisheye"], "camera.view", "unknown view"),
])
def test_bad_camera_factors_name_their_key(overrides, key, words):
    with pytest.raises(GarageError) as err:
        check_camera(rig(*overrides))
    assert key in str(err.value) and words in str(err.value)


def hits(triangles: np.ndarray, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Which rays from origin hit any triangle (Moller-Trumbore, vectorised; trimesh's ray module needs rtree)."""
    v0, e1, e2 = triangles[:, 0], triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    t0 = origin - v0
    q = np.cross(t0, e1)
    out = np.zeros(len(dirs), dtype=bool)
    for s in range(0, len(dirs), 128):
        d = dirs[s:s + 128, None, :]
        p = np.cross(d, e2[None])
        det = np.einsum("rtk,tk->rt", p, e1)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        u = np.einsum("tk,rtk->rt", t0, p) * inv
        v = (d[:, 0] @ q.T) * inv
        t = (e2 * q).sum(axis=1)[None] * inv
        out[s:s + 128] = (ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-4)).any(axis=1)
    return out


def body_rows(triangles, spec: CameraSpec, w: int = 32, h: int = 24) -> np.ndarray:
    """Per image row (top first), the share of the camera's pixel rays that hit the ego's body."""
    f = h / 2 / math.tan(math.radians(spec.fovy) / 2)
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    local = np.stack([np.full(u.size, f), -(u.ravel() - w / 2), -(v.ravel() - h / 2)], axis=1)
    pose = camera_to_world(Pose(), spec)
    return hits(triangles, pose[:3, 3], local @ pose[:3, :3].T).reshape(h, w).mean(axis=1)


def test_the_ego_shows_only_where_a_camera_at_the_mount_would_see_it():
    require("vehicles")
    import trimesh

    from garage_exp.assets.vehicles import VehicleLibrary

    model = VehicleLibrary().get("tcamrysilver")
    triangles = trimesh.load(model.glb, force="mesh").triangles
    extent = (model.length, model.width, model.height)
    for name in MOUNTS:
        for fovy in (60.0, 120.0):
            rows = body_rows(triangles, CameraSpec(name, mount_pose(name, extent), fovy=fovy))
            if name in ("roof", "mirror"):
                # the bonnet below the horizon, as from a real roof or windscreen camera; never above it
                assert rows[: len(rows) // 2].max() == 0.0 and rows[-1] > 0.5, (name, fovy, rows)
            else:  # bumper, side mirrors and rear sit outside the body, facing away from it
                assert rows.max() == 0.0, (name, fovy, rows)
    # the legacy roof camera (camera=front, kept for the golden tables) sees the bonnet in its bottom fifth
    legacy = body_rows(triangles, CameraSpec("front", Pose(0.3, 0.0, model.height + 0.05), fovy=60.0))
    assert legacy[: int(len(legacy) * 0.75)].max() == 0.0 and legacy[-1] > 0.9
