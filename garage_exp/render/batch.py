"""The GPU path (`renderer.device=cuda`): a batch of shots rendered at once, one SAPIEN sub-scene per trial or
environment in flight, with pictures that stay on the GPU.

Recipe (../shared/FACTS.md, "SAPIEN and YOLO on an NVIDIA H100"): each sub-scene is the project's own scene
(`SapienRenderer` builds it, so materials, lamps and merged statics are the CPU path's); every camera and every
render shape of a moving actor gets a row of one pose tensor (`set_gpu_pose_batch_index`), a torch float32 CUDA
tensor of rows (p xyz, q wxyz, 6 unused) handed to `RenderSystemGroup.set_cuda_poses`; a frame writes poses
into the tensor, `update_render()`, `take_picture()` on a camera group, and reads Color and Segmentation as CUDA
tensors. Silhouettes (ground truth's unoccluded masks) are one more group picture per actor slot with everything
else hidden in every sub-scene. Ground truth's pixel work and the camera model then run in torch
(perception/batch_truth.py, batch_sensor.py), and only numbers leave the GPU.

What runs without a GPU (and is tested on the CPU): `Layout` (which row each posed thing has), `pose_rows`
(4x4 poses -> rows), `pack` (a batch of shots -> the tensor's rows). `BatchRenderer` needs CUDA and refuses in
one line otherwise (`require_cuda`). Unmeasured here: no GPU was lent to the session that wrote it;
benchmarks/gpu_pipeline.py checks it against the CPU path on the GPU machine.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.description import Pose

ROW = 13  # p xyz, q wxyz, 6 unused (SAPIEN's pose buffer layout)


def require_cuda() -> None:
    """GarageError (one line) unless torch sees a CUDA device: the batched path renders and computes there."""
    try:
        import torch
    except ImportError:
        raise GarageError("renderer.device=cuda needs torch with CUDA; torch is not installed",
                          "renderer.device") from None
    if not torch.cuda.is_available():
        raise GarageError("renderer.device=cuda needs a CUDA GPU; none is visible here (use renderer.device=auto)",
                          "renderer.device")


@dataclass(frozen=True)
class Layout:
    """Rows of the pose tensor: for each of `scenes` sub-scenes, one row per camera (its lit and silhouette
    components share it) and one per moving actor (all its render shapes share it), in that order."""

    scenes: int
    cameras: tuple[str, ...]
    actors: tuple[str, ...]

    @property
    def per_scene(self) -> int:
        return len(self.cameras) + len(self.actors)

    @property
    def rows(self) -> int:
        return self.scenes * self.per_scene

    def row(self, scene: int, name: str) -> int:
        """The row of camera or actor `name` in sub-scene `scene`."""
        if not 0 <= scene < self.scenes:
            raise IndexError(f"sub-scene {scene} of {self.scenes}")
        names = (*self.cameras, *self.actors)
        if name not in names:
            raise KeyError(f"{name!r} is neither a camera nor a moving actor of the batch")
        return scene * self.per_scene + names.index(name)


def quaternion(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions w, x, y, z (w >= 0), robust for every angle
    (the largest of the four candidates' squares picks the formula)."""
    rot = np.asarray(rot, dtype=np.float64)
    m = rot.reshape(-1, 3, 3)
    out = np.empty((len(m), 4))
    for i, r in enumerate(m):
        t = np.trace(r)
        cands = [t, r[0, 0], r[1, 1], r[2, 2]]
        k = int(np.argmax(cands))
        if k == 0:
            s = np.sqrt(1.0 + t) * 2
            q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        elif k == 1:
            s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
            q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
        elif k == 2:
            s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
            q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
        else:
            s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
            q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
        q = np.asarray(q)
        out[i] = q if q[0] >= 0 else -q
    return out.reshape(*rot.shape[:-2], 4)


def pose_rows(matrices: np.ndarray) -> np.ndarray:
    """(M, 4, 4) world poses -> (M, 13) float32 rows of SAPIEN's pose buffer."""
    matrices = np.asarray(matrices, dtype=np.float64).reshape(-1, 4, 4)
    out = np.zeros((len(matrices), ROW), np.float32)
    out[:, :3] = matrices[:, :3, 3]
    out[:, 3:7] = quaternion(matrices[:, :3, :3])
    return out


def actor_matrix(pose: Pose) -> np.ndarray:
    """An actor's 4x4 world pose (yaw about +z), as `sapien_backend._sapien_pose` places it."""
    c, s = np.cos(np.radians(pose.yaw)), np.sin(np.radians(pose.yaw))
    m = np.eye(4)
    m[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    m[:3, 3] = [pose.x, pose.y, pose.z]
    return m


def pack(layout: Layout, shots: Sequence, specs: dict, hidden: Pose, rest: dict) -> np.ndarray:
    """A batch of shots (at most `layout.scenes`; shot i in sub-scene i) as the pose tensor's rows: each
    camera at the ego's pose (`scene.camera.camera_to_world`, `specs` by name), each actor at its pose in the
    shot (`hidden` when None: out of sight), else at `rest` (name -> its scene pose: `shot.poses` holds only the
    case's actors, parked cars stand still). Rows of sub-scenes without a shot keep identity poses."""
    if len(shots) > layout.scenes:
        raise ValueError(f"{len(shots)} shots for {layout.scenes} sub-scenes")
    mats = np.tile(np.eye(4), (layout.rows, 1, 1))
    for i, shot in enumerate(shots):
        for cam in layout.cameras:
            mats[layout.row(i, cam)] = camera_to_world(shot.ego, specs[cam])
        for name in layout.actors:
            pose = shot.ego if name == "ego" else shot.poses[name] if name in shot.poses else rest[name]
            mats[layout.row(i, name)] = actor_matrix(hidden if pose is None else pose)
    return pose_rows(mats)


class BatchRenderer:
    """`scenes` copies of one scene description in a `RenderSystemGroup`, rendered a batch of shots at a time on
    the GPU. Pinhole cameras only (a fisheye rig's faces are pinhole crops: render those and remap them with
    render/fisheye_torch.py). Needs CUDA (`require_cuda`)."""

    def __init__(self, scene, scenes: int, hidden: Pose, max_lights: int = 8, camera: str | None = None):
        require_cuda()
        import sapien
        import torch

        from garage_exp.render.sapien_backend import SapienRenderer
        from garage_exp.render.sapien_builder import DECALS

        spec = next((c for c in scene.cameras if c.name == camera), scene.cameras[0]) if camera else scene.cameras[0]
        if spec.fisheye:
            raise GarageError("the batched renderer takes pinhole cameras; a fisheye is rendered as its faces",
                              "renderer.device")
        self.scene, self.spec, self.hidden = scene, spec, hidden  # hidden: where an absent actor waits
        self.subs = []
        for _ in range(scenes):  # each its own sapien.Scene, built as the CPU path builds it
            sub = SapienRenderer(max_lights=max_lights, device="cuda", cull=False)
            sub.load(scene)
            self.subs.append(sub)
        movers = tuple(n for n in self.subs[0]._built.entities if n != self.subs[0]._ego and not n.endswith(DECALS))
        self.layout = Layout(scenes, (spec.name,), ("ego", *movers))
        ego = self.subs[0]._ego
        for i, sub in enumerate(self.subs):
            cam = sub._cameras[spec.name]
            for component in (cam.component, cam.silhouette):
                component.set_gpu_pose_batch_index(self.layout.row(i, spec.name))
            for name in self.layout.actors:
                entity = ego if name == "ego" else name
                entities = sub._built.entities
                for node in (entities.get(entity), entities.get(entity + DECALS)):  # its contact shadow too
                    for body in (node.components if node is not None else []):
                        for shape in getattr(body, "render_shapes", []):
                            shape.set_gpu_pose_batch_index(self.layout.row(i, name))
        self.group = sapien.render.RenderSystemGroup([sub._built.scene.render_system for sub in self.subs])
        self.lit = self.group.create_camera_group([s._cameras[spec.name].component for s in self.subs],
                                                  ["Color", "Segmentation"])
        self.ids_only = self.group.create_camera_group([s._cameras[spec.name].silhouette for s in self.subs],
                                                       ["PositionSegmentation"])
        self.poses = torch.zeros((self.layout.rows, ROW), dtype=torch.float32, device="cuda")
        self.group.set_cuda_poses(sapien.pysapien.CudaArray(self.poses))  # noqa: the tensor's memory, kept

    def _pose(self, shots: Sequence) -> None:
        import torch

        specs = {self.spec.name: self.spec}
        rest = {e.name: e.pose for e in self.scene.entities}
        self.poses.copy_(torch.from_numpy(pack(self.layout, shots, specs, self.hidden, rest)))
        for sub, shot in zip(self.subs, shots):  # the light pool follows each camera (CPU-side, per sub-scene)
            sub._place(sub._cameras[self.spec.name], camera_to_world(shot.ego, self.spec))
            sub.bodies.show_only(sub.bodies.base)
        self.group.update_render()

    def render(self, shots: Sequence):
        """Colour (N, H, W, 3) uint8 and ids (N, H, W) int32 CUDA tensors of the shots (N = len(shots))."""
        import torch

        self._pose(shots)
        self.lit.take_picture()
        n = len(shots)
        rgba = torch.as_tensor(self.lit.get_picture_cuda("Color"), device="cuda")[:n]
        seg = torch.as_tensor(self.lit.get_picture_cuda("Segmentation"), device="cuda")[:n]
        rgb = (rgba[..., :3].clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8)  # as SapienRenderer._take rounds
        return rgb, seg[..., 1].to(torch.int32)

    def silhouettes(self, shots: Sequence, names: Sequence[str]):
        """(N, K, H, W) bool CUDA masks: actor k alone in each sub-scene (K = len(names)); the ids picture's
        channel 3, as `SapienRenderer._take_ids` reads it."""
        import torch

        if not names:
            return torch.zeros((len(shots), 0, self.spec.height, self.spec.width), dtype=torch.bool, device="cuda")
        masks = []
        for name in names:
            for sub in self.subs:
                sub.bodies.show_only(sub.bodies.only([name]))
            self.group.update_render()
            self.ids_only.take_picture()
            ids = torch.as_tensor(self.ids_only.get_picture_cuda("PositionSegmentation"), device="cuda")
            masks.append(ids[: len(shots), ..., 3] == self.subs[0].ids[name])
        for sub in self.subs:
            sub.bodies.show_only(sub.bodies.base)
        return torch.stack(masks, dim=1)
