"""The cylindrical lens: columns linear in azimuth, rows linear in tan(elevation), a common undistortion for wide
lenses. The layout of a view (scene/views.py `cylindrical`); no camera is of this model."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from garage_exp.scene.lenses.base import Lens, SquarePixels, grid, register_lens, unit


@register_lens("cylindrical")
@dataclass(frozen=True)
class Cylindrical(SquarePixels, Lens):
    f: float  # pixels per radian of azimuth, and per unit of tan(elevation)
    cx: float
    cy: float
    camera_model = False

    @classmethod
    def from_fovx(cls, width: int, height: int, fovx: float) -> Cylindrical:
        return cls(width, height, width / math.radians(fovx), width / 2.0, height / 2.0)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        u, v = grid(self.width, self.height)
        phi = (u - self.cx) / self.f  # to the right
        d = np.stack([np.cos(phi), -np.sin(phi), -(v - self.cy) / self.f], axis=-1)
        return unit(d), np.ones(u.shape, dtype=bool)

    def project(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.asarray(d, dtype=float)
        flat = np.hypot(d[..., 0], d[..., 1])
        return (self.cx + self.f * np.arctan2(-d[..., 1], d[..., 0]),
                self.cy - self.f * d[..., 2] / np.where(flat > 1e-12, flat, np.nan))
