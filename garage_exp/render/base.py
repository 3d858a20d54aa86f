"""What every renderer gives the job: a `Frame` per camera, and the `Renderer` interface.

Plain data, no SAPIEN: ground truth and tests use `Frame` without a Vulkan device. A backend is a module with a
factory returning a `Renderer`, registered under a word (`render.registry.register_backend`, `renderer.backend`);
the render scene (render/batch.py) batches any `Renderer` through the members named here and nothing else.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from garage_exp.scene.camera import to_camera, to_pixels
from garage_exp.scene.description import Pose, Scene

BLANK_GREY = 128  # the blank control's background value (8-bit sRGB, all channels)


@dataclass
class Frame:
    """One camera's picture.

    rgb: HxWx3 uint8 (sRGB). ids: HxW int32, the id of the entity seen in each pixel (0: nothing; `Renderer.ids`
    maps names to ids). cam_to_world: 4x4 pose of the camera with SAPIEN's camera axes (x forward, y left,
    z up). fx, fy, cx, cy: pinhole intrinsics in pixels (garage_exp.scene.camera), unless `lens` is set.
    poses: where each vehicle (and the ego) stood when this was rendered.
    """

    camera: str
    rgb: np.ndarray
    ids: np.ndarray
    cam_to_world: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    poses: dict[str, Pose] = field(default_factory=dict)
    # A fisheye or cylindrical frame's lens (render/fisheye.py); None: the pinhole fx, fy, cx, cy above. For a
    # fisheye, fx = fy is the lens's f and (cx, cy) its centre.
    lens: object | None = None
    # Ids of flat pictures on the floor (contact shadows, painted arrows): they may cover an actor's lowest
    # millimetres, and ground truth counts such pixels as the actor's, not as occluded.
    see_through: frozenset[int] = frozenset()
    # Ids of the structure's pillars (merged static bodies made only of pillars, or pillars with their own id):
    # ground truth names what hides an actor `pillar` when these pixels cover it (perception/groundtruth.py).
    pillars: frozenset[int] = frozenset()

    @property
    def width(self) -> int:
        return int(self.ids.shape[1])

    @property
    def height(self) -> int:
        return int(self.ids.shape[0])

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        return self.fx, self.fy, self.cx, self.cy

    @property
    def position(self) -> np.ndarray:
        return self.cam_to_world[:3, 3].copy()

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N x 3) -> pixel coordinates (N x 2, continuous) and depth along the view axis (N)."""
        local = to_camera(self.cam_to_world, points)
        depth = local[:, 0]
        if self.lens is not None:
            u, v = self.lens.project(local)
            return np.stack([u, v], axis=1), depth
        safe = np.where(np.abs(depth) < 1e-9, 1e-9, depth)
        u, v = to_pixels(local, self.intrinsics, safe)
        return np.stack([u, v], axis=1), depth


class Renderer(Protocol):
    """One sub-scene of a render scene (render/batch.py), which reads a backend only through these members. One
    instance per process is expected for sub-scene 0 (compiled shaders); `sibling` makes the others."""

    description: Scene | None  # the scene description loaded last (None before a load): a load of it is skipped

    def load(self, scene: Scene) -> None:
        """(Re)build from a scene description; cameras, lights and ids are replaced."""

    @property
    def ids(self) -> dict[str, int]:
        """Entity name -> the id its pixels carry in `Frame.ids` (every entity that moves or is scored)."""

    def set_pose(self, name: str, pose: Pose) -> None:
        """Move an entity with its own id (a vehicle; the ego, which carries the cameras)."""

    def render(self, camera_name: str) -> Frame:
        """One camera's colour and ids, with its pose (garage_exp.scene.camera) and intrinsics."""

    def unoccluded_ids(self, camera_name: str, names: Iterable[str]) -> dict[str, np.ndarray]:
        """Each named entity's silhouette (HxW bool) as the camera would see it with nothing in the way; entities
        outside the image are left out."""

    def restyle(self, change: dict) -> None:
        """Give the loaded materials other pictures (old -> new `Material`s: a replicate's stains and wetness);
        a backend without textures does nothing."""

    def sibling(self) -> "Renderer":
        """A new renderer with these settings: another sub-scene of the render scene (`renderer.scenes` > 1)."""
