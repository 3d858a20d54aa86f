"""The GPU path's batching logic (render/sapien_batch.py) on the CPU: rows of the pose tensor, rotation matrices to
SAPIEN's quaternions, a batch of shots packed; and the one-line refusal where no CUDA device is."""

from __future__ import annotations

import numpy as np
import pytest

from garage_exp.core.errors import GarageError
from garage_exp.render.sapien_batch import Layout, actor_matrix, pack, pose_rows, quaternion, require_cuda
from garage_exp.scenario import Shot
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.description import CameraSpec, Pose


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_layout_rows_are_distinct_and_scene_major():
    layout = Layout(3, ("front",), ("ego", "target", "parked_1"))
    rows = [layout.row(s, n) for s in range(3) for n in ("front", "ego", "target", "parked_1")]
    assert rows == list(range(12)) and layout.rows == 12
    with pytest.raises(IndexError):
        layout.row(3, "front")
    with pytest.raises(KeyError):
        layout.row(0, "nobody")


def test_quaternion_matches_sapien_for_every_kind_of_rotation():
    sapien = pytest.importorskip("sapien")
    rng = np.random.default_rng(0)
    rots = [rotation(rng.normal(size=3), a) for a in (0.0, 0.3, np.pi / 2, np.pi - 1e-7, np.pi)]
    rots += [rotation([1, 0, 0], np.pi), rotation([0, 1, 0], np.pi), rotation([0, 0, 1], np.pi)]
    for r in rots:
        m = np.eye(4)
        m[:3, :3] = r
        want = np.asarray(sapien.Pose(m.astype(np.float32)).q, float)
        got = quaternion(r)
        assert min(np.abs(got - want).max(), np.abs(got + want).max()) < 1e-6
        assert got[0] >= 0


def test_pack_puts_cameras_at_the_ego_and_actors_at_their_shot_poses():
    spec = CameraSpec("front", Pose(2.0, 0.0, 1.2), width=64, height=48)
    layout = Layout(3, ("front",), ("ego", "target", "parked"))
    hidden, parked = Pose(0.0, 0.0, -50.0), Pose(9.0, 9.0, 0.0, 90.0)
    shots = [Shot(0, "", 0.0, Pose(1.0, 2.0, 0.0, 30.0), {"target": Pose(5.0, 0.0, 0.0, 90.0)}, "target"),
             Shot(1, "", 0.0, Pose(-1.0, 0.0, 0.0, 180.0), {"target": None}, "target")]
    rows = pack(layout, shots, {"front": spec}, hidden, {"parked": parked, "target": Pose()})
    assert rows.shape == (12, 13) and rows.dtype == np.float32
    np.testing.assert_allclose(rows[layout.row(1, "front")], pose_rows(camera_to_world(shots[1].ego, spec))[0],
                               atol=1e-6)
    np.testing.assert_allclose(rows[layout.row(0, "target")], pose_rows(actor_matrix(Pose(5.0, 0.0, 0.0, 90.0)))[0],
                               atol=1e-6)
    assert rows[layout.row(1, "target"), 2] == -50.0  # not in this variant: out of sight
    np.testing.assert_allclose(rows[layout.row(0, "parked")], pose_rows(actor_matrix(parked))[0], atol=1e-6)
    assert (rows[layout.row(2, "ego"), :7] == [0, 0, 0, 1, 0, 0, 0]).all()  # no shot: identity
    with pytest.raises(ValueError, match="4 shots for 3"):
        pack(layout, shots * 2, {"front": spec}, hidden, {})


def test_the_cuda_path_refuses_in_one_line_without_a_gpu():
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is here")
    with pytest.raises(GarageError, match="renderer.device: renderer.device=cuda needs a CUDA GPU"):
        require_cuda()
