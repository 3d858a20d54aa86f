"""Rendering: a Frame (picture, entity ids, camera) and the process-wide SAPIEN renderer.

Importing this package does not import SAPIEN: `Frame` is plain data that ground truth and tests use without a
Vulkan device; `get_renderer()` loads the backend on first use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from garage_exp.scene.description import CameraSpec, Pose

if TYPE_CHECKING:
    from garage_exp.render.sapien_backend import SapienRenderer

BLANK_GREY = 128  # the blank control's background value (8-bit sRGB, all channels)


@dataclass
class Frame:
    """One camera's picture.

    rgb: HxWx3 uint8 (sRGB). ids: HxW int32, the SAPIEN `per_scene_id` of the entity seen in each pixel (0:
    nothing). cam_to_world: 4x4 pose of the camera with SAPIEN's camera axes (x forward, y left, z up).
    fx, fy, cx, cy: pinhole intrinsics in pixels; a pixel (col, row) spans [col, col+1) x [row, row+1), so the
    image centre is (width/2, height/2). poses: where each vehicle (and the ego) stood when this was rendered.
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
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        local = (pts - self.cam_to_world[:3, 3]) @ self.cam_to_world[:3, :3]
        depth = local[:, 0]
        safe = np.where(np.abs(depth) < 1e-9, 1e-9, depth)
        u = self.cx - self.fx * local[:, 1] / safe
        v = self.cy - self.fy * local[:, 2] / safe
        return np.stack([u, v], axis=1), depth


def intrinsics_of(spec: CameraSpec) -> tuple[float, float, float, float]:
    """fx, fy, cx, cy of a camera from its vertical FOV, with square pixels."""
    fy = spec.height / 2.0 / math.tan(math.radians(spec.fovy) / 2.0)
    return fy, fy, spec.width / 2.0, spec.height / 2.0


def camera_to_world(ego: Pose, spec: CameraSpec) -> np.ndarray:
    """The camera's 4x4 pose: the ego's pose, then the mount (offset and yaw), then the pitch (positive down)."""
    mount = ego.compose(spec.mount)
    yaw, pitch = math.radians(mount.yaw), math.radians(spec.pitch)
    cz, sz, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    # A positive rotation about the camera's y (left) axis turns its x (forward) axis downwards.
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    out = np.eye(4)
    out[:3, :3] = rz @ ry
    out[:3, 3] = (mount.x, mount.y, mount.z)
    return out


def get_renderer(max_lights: int = 8, shadows: bool = False) -> "SapienRenderer":
    """The process's renderer (created on first call, then reused so shaders compile once per process)."""
    from garage_exp.render.sapien_backend import get_renderer as _get

    return _get(max_lights=max_lights, shadows=shadows)


__all__ = ["BLANK_GREY", "Frame", "camera_to_world", "get_renderer", "intrinsics_of"]
