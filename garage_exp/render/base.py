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

from garage_exp.scene.camera import to_camera
from garage_exp.scene.description import Pose, Scene
from garage_exp.scene.lenses import Lens

BLANK_GREY = 128  # the blank control's background value (8-bit sRGB, all channels)


@dataclass
class Frame:
    """One camera's picture.

    rgb: HxWx3 uint8 (sRGB). ids: HxW int32, the id of the entity seen in each pixel (0: nothing; `Renderer.ids`
    maps names to ids). cam_to_world: 4x4 pose of the camera with SAPIEN's camera axes (x forward, y left,
    z up). lens: the picture's lens (scene/lenses: its intrinsics, its projection; `scene.views.picture_lens` of
    the camera's spec). poses: where each vehicle (and the ego) stood when this was rendered.
    """

    camera: str
    rgb: np.ndarray
    ids: np.ndarray
    cam_to_world: np.ndarray
    lens: Lens
    poses: dict[str, Pose] = field(default_factory=dict)
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
    def position(self) -> np.ndarray:
        return self.cam_to_world[:3, 3].copy()

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N x 3) -> pixel coordinates (N x 2, continuous) and depth along the view axis (N). A
        perspective lens divides by the depth, kept away from 0 (a point behind it mirrors through its centre)."""
        local = to_camera(self.cam_to_world, points)
        depth = local[:, 0]
        if not self.lens.perspective:
            u, v = self.lens.project(local)
            return np.stack([u, v], axis=1), depth
        u, v = self.lens.pixels(local, np.where(np.abs(depth) < 1e-9, 1e-9, depth))
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
