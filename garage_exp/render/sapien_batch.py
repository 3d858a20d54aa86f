"""The SAPIEN backend's own batch: the render scene's CUDA branch (`renderer.device=cuda`), the N sub-scenes' SAPIEN
scenes in one `sapien.render.RenderSystemGroup` (`CudaScene` over a `CudaGroup`), pictures as torch CUDA tensors;
ground truth and the camera model then run on them in torch (perception/groundtruth.py and sensor.py take numpy
or torch), and the frame goes to numpy for the detector. Callers see the render scene of render/batch.py (its
`load` and `render_batch`), opened by `render.open.open_renderer`; on any other device the SAPIEN backend's scene is
that generic one (`open_scene`).

The CUDA recipe (../shared/FACTS.md, "SAPIEN and YOLO on an NVIDIA H100"): each sub-scene is the project's own scene
(`SapienRenderer` builds it, so materials, lamps and merged statics are the CPU path's); every camera and every
render shape of a moving actor gets a row of one pose tensor (`set_gpu_pose_batch_index`), a torch float32 CUDA
tensor of rows (p xyz, q wxyz, 6 unused) handed to `RenderSystemGroup.set_cuda_poses`; a batch writes poses into
the tensor, `update_render()`, `take_picture()` on a camera group per camera, and reads Color and Segmentation as
CUDA tensors. Silhouettes are one more group picture per actor with everything else hidden in every sub-scene.
It is the SAPIEN backend's, so it reads `SapienRenderer`'s own members (`camera_components`, `render_shapes`,
`movers`, `place_camera`, `show`, `sapien_scene`); nothing outside the SAPIEN modules does. Pinhole cameras
only (a fisheye's cube faces are not batched).

What runs without a GPU (and is tested on the CPU): `Layout` (which row each posed thing has), `pose_rows` (4x4
poses -> rows), `pack` (a batch of shots -> the tensor's rows). The CUDA branch needs CUDA and refuses in one
line otherwise (`require_cuda`). benchmarks/performance/gpu_pipeline.py checks it against the CPU path on the GPU
machine (docs/gpu.md).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.render.base import BLANK_GREY, Frame
from garage_exp.render.batch import RenderScene, Take
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


class CudaScene(RenderScene):
    """The render scene's CUDA branch: N SAPIEN sub-scenes built alike (no culling: one pose tensor poses every
    sub-scene) whose batch is one `CudaGroup` picture per camera."""

    def __init__(self, subs: Sequence, hidden: Pose):
        super().__init__(subs, hidden)
        self._group: CudaGroup | None = None  # built on load

    @property
    def gpu(self) -> "CudaGroup | None":
        """The group (its RenderSystemGroup and camera groups), for the GPU benchmark's ceiling."""
        return self._group

    def load(self, scene) -> None:
        """A new description gets new sub-scenes (nothing can be added to a SAPIEN scene once it is in a group),
        then one group over them."""
        if any(sub.description is not scene for sub in self.subs):
            self.subs = [sub.sibling(cull=False) for sub in self.subs]
            self._group = None
        super().load(scene)
        if self._group is None:
            self._group = CudaGroup(self.subs, scene, self.hidden)

    def takes(self, shots: Sequence, cameras: Sequence[str], actors: Sequence[Sequence[str]]) -> list[Take]:
        return self._group.render(shots, cameras, actors)


def open_scene(first: Callable[[], object], n: int, hidden: Pose, device: str = "auto", **_settings) -> RenderScene:
    """The SAPIEN backend's render scene of `n` sub-scenes (`first()`: the process's renderer): the CUDA branch
    under `renderer.device=cuda` (refused in one line without a GPU, before any SAPIEN scene is made), else the
    generic one, sub-scenes rendered one after another. The group's other keys are the factory's (`first`)."""
    if device != "cuda":
        return RenderScene.of(first(), n, hidden)
    require_cuda()
    warm = first()
    return CudaScene([warm.sibling(cull=False) for _ in range(n)], hidden)


class CudaGroup:
    """The CUDA branch's pictures (`CudaScene`): the sub-scenes' SAPIEN scenes in one RenderSystemGroup, a camera group
    per camera (lit: Color and Segmentation; its ids-only twins: PositionSegmentation), poses from one CUDA
    tensor. Needs CUDA (`require_cuda`)."""

    def __init__(self, subs: Sequence, scene, hidden: Pose):
        require_cuda()
        import sapien
        import torch

        if any(spec.fisheye for spec in scene.cameras):
            raise GarageError("the batched renderer takes pinhole cameras; render a fisheye rig with "
                              "renderer.device=auto or cpu", "renderer.device")
        self.subs, self.scene, self.hidden = list(subs), scene, hidden
        self.specs = {spec.name: spec for spec in scene.cameras}
        first = self.subs[0]
        self.layout = Layout(len(self.subs), tuple(self.specs), ("ego", *first.movers))
        for i, sub in enumerate(self.subs):
            for name in self.specs:
                for component in sub.camera_components(name):
                    component.set_gpu_pose_batch_index(self.layout.row(i, name))
            for name in self.layout.actors:
                for shape in sub.render_shapes(sub.ego if name == "ego" else name):
                    shape.set_gpu_pose_batch_index(self.layout.row(i, name))
        self.group = sapien.render.RenderSystemGroup([sub.sapien_scene.render_system for sub in self.subs])
        self.lit = {name: self.group.create_camera_group([sub.camera_components(name)[0] for sub in self.subs],
                                                         ["Color", "Segmentation"]) for name in self.specs}
        self.ids_only = {name: self.group.create_camera_group(
            [sub.camera_components(name)[1] for sub in self.subs], ["PositionSegmentation"]) for name in self.specs}
        self.poses = torch.zeros((self.layout.rows, ROW), dtype=torch.float32, device="cuda")
        self.group.set_cuda_poses(sapien.pysapien.CudaArray(self.poses))  # the tensor's memory, kept
        self.rest = {e.name: e.pose for e in scene.entities}
        self.vehicles, self.ego = first.vehicles, first.ego
        self.see_through = first.decal_ids
        self.pillars = first.pillar_ids

    def render(self, shots: Sequence, cameras: Sequence[str], actors: Sequence[Sequence[str]]) -> list[Take]:
        import torch

        from garage_exp.scene.lenses import lens_of

        self.poses.copy_(torch.from_numpy(pack(self.layout, shots, self.specs, self.hidden, self.rest)))
        n, frames = len(shots), {}
        for camera in cameras:
            for sub, shot in zip(self.subs, shots):  # the light pool follows each camera (CPU-side, per sub-scene)
                sub.place_camera(camera, camera_to_world(shot.ego, self.specs[camera]))
                sub.show()
            self.group.update_render()
            lit = self.lit[camera]
            lit.take_picture()
            rgba = torch.as_tensor(lit.get_picture_cuda("Color"), device="cuda")[:n]
            seg = torch.as_tensor(lit.get_picture_cuda("Segmentation"), device="cuda")[:n]
            rgb = (rgba[..., :3].clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8)  # as sapien_cameras.take rounds
            ids = seg[..., 1].to(torch.int32)
            if not self.scene.background:
                rgb[ids == 0] = BLANK_GREY
            frames[camera] = (rgb, ids, self._silhouettes(camera, n, sorted({a for names in actors for a in names})))
        takes = []
        for k, shot in enumerate(shots):
            for camera in cameras:
                rgb, ids, masks = frames[camera]
                spec = self.specs[camera]
                frame = Frame(camera, rgb[k], ids[k], camera_to_world(shot.ego, spec), lens_of(spec),
                              self._vehicle_poses(shot), see_through=self.see_through,
                              pillars=self.pillars)
                takes.append(Take(shot, camera, frame, {a: masks[a][k] for a in actors[k]}, self.subs[k].ids))
        return takes

    def _silhouettes(self, camera: str, n: int, names: Sequence[str]) -> dict:
        """name -> (n, H, W) bool CUDA masks: the actor alone in each sub-scene; the ids picture's channel 3, as
        `sapien_cameras.take_ids` reads it."""
        import torch

        masks = {}
        group = self.ids_only[camera]
        for name in names:
            for sub in self.subs:
                sub.show([name])
            self.group.update_render()
            group.take_picture()
            ids = torch.as_tensor(group.get_picture_cuda("PositionSegmentation"), device="cuda")
            mine = torch.tensor([sub.ids[name] for sub in self.subs[:n]], device="cuda").view(-1, 1, 1)
            masks[name] = ids[:n, ..., 3] == mine
        for sub in self.subs:
            sub.show()
        return masks

    def _vehicle_poses(self, shot) -> dict[str, Pose]:
        """Where each vehicle stood in the shot (`Frame.poses`): the shot's pose, else the scene's."""
        out = {}
        for name in self.vehicles:
            pose = shot.ego if name == self.ego else shot.poses[name] if name in shot.poses else self.rest.get(name)
            out[name] = self.hidden if pose is None else pose
        return out
