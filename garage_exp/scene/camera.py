"""The camera: its config check, its pose on the ego, its intrinsics and the world -> pixel projection.

Plain numpy: the renderer, ground truth and tests all project with these functions, so a second renderer only
has to agree with them. Camera axes are SAPIEN's (x forward, y left, z up); a pixel (col, row) spans
[col, col+1) x [row, row+1), so the image centre is (width/2, height/2).
"""

from __future__ import annotations

import math

import numpy as np

from garage_exp.errors import GarageError, check_range
from garage_exp.scene.description import CameraSpec, Pose

FOVY_RANGE = (1.0, 170.0)  # degrees, vertical
RESOLUTION_RANGE = (16, 4096)  # pixels per side


def check_camera(rig) -> None:
    """The `camera` group: at least one camera, each with a sane field of view and size."""
    if not rig.cameras:
        raise GarageError("the rig has no camera", "camera.cameras")
    for k, cam in enumerate(rig.cameras):
        check_range(cam.fovy, *FOVY_RANGE, f"camera.cameras.{k}.fovy", f"fovy {cam.fovy} degrees")
        for side in ("width", "height"):
            check_range(cam[side], *RESOLUTION_RANGE, f"camera.cameras.{k}.{side}", f"{side} {cam[side]} px")


def rig_specs(rig, ego_height: float) -> list[CameraSpec]:
    """The rig's cameras, mounted on an ego of this height (`rig.roof`: z counts from its roof)."""
    roof = ego_height if rig.roof else 0.0
    return [CameraSpec(cam.name, Pose(cam.x, cam.y, roof + cam.z, cam.yaw), pitch=cam.pitch, fovy=cam.fovy,
                       width=cam.width, height=cam.height) for cam in rig.cameras]


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


def to_camera(cam_to_world: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World points (N x 3) in the camera's frame (x: depth along the view axis)."""
    return (np.asarray(points, dtype=float).reshape(-1, 3) - cam_to_world[:3, 3]) @ cam_to_world[:3, :3]


def to_pixels(local: np.ndarray, intrinsics: tuple[float, float, float, float],
              depth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (N x 3) -> continuous pixel coordinates u (column), v (row). `depth` replaces the
    points' own x (callers keep it away from 0)."""
    fx, fy, cx, cy = intrinsics
    depth = local[:, 0] if depth is None else depth
    return cx - fx * local[:, 1] / depth, cy - fy * local[:, 2] / depth
