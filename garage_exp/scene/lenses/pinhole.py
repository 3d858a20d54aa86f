"""The pinhole lens: a central projection onto the image plane (a plain camera, a cube face, a perspective view
undistorted from a fisheye). A camera of this model is drawn as one picture; `fovy` sets its focal length."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from garage_exp.core.errors import check_range
from garage_exp.scene.lenses.base import Lens, grid, register_lens, unit

FOVY_RANGE = (1.0, 170.0)  # degrees, vertical


@register_lens("pinhole")
@dataclass(frozen=True)
class Pinhole(Lens):
    fx: float
    fy: float
    cx: float
    cy: float
    perspective: ClassVar[bool] = True

    @classmethod
    def check(cls, cam, rig, where: str) -> None:
        key = "camera.fovy" if rig.fovy is not None else f"{where}.fovy"
        check_range(cam.fovy, *FOVY_RANGE, key, f"fovy {cam.fovy} degrees")

    @classmethod
    def of(cls, spec) -> Pinhole:
        return cls.from_fovy(spec.width, spec.height, spec.fovy)

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy: float) -> Pinhole:
        """Square pixels, the centre in the middle, `fovy` degrees across the height."""
        f = height / 2.0 / math.tan(math.radians(fovy) / 2.0)
        return cls(width, height, f, f, width / 2.0, height / 2.0)

    @classmethod
    def from_fovx(cls, width: int, height: int, fovx: float) -> Pinhole:
        """Square pixels, the centre in the middle, `fovx` degrees across the width."""
        f = width / 2.0 / math.tan(math.radians(fovx) / 2.0)
        return cls(width, height, f, f, width / 2.0, height / 2.0)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        u, v = grid(self.width, self.height)
        d = np.stack([np.ones_like(u), -(u - self.cx) / self.fx, -(v - self.cy) / self.fy], axis=-1)
        return unit(d), np.ones(u.shape, dtype=bool)

    def project(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel coordinates; rays at or behind the image plane get NaN."""
        d = np.asarray(d, dtype=float)
        return self.pixels(d, np.where(d[..., 0] > 1e-9, d[..., 0], np.nan))

    def pixels(self, local: np.ndarray, depth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points (...x3) divided by their depth: u (column), v (row). `depth` replaces the points'
        own x (callers keep it away from 0; a point behind the camera mirrors through its centre)."""
        depth = local[..., 0] if depth is None else depth
        return self.cx - self.fx * local[..., 1] / depth, self.cy - self.fy * local[..., 2] / depth
