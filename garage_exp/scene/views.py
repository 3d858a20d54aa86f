"""The views a lens camera's detector gets (`camera.view`): the raw image, or a view undistorted from it. A
registry: each view is registered beside its class with `@register_view(NAME)`, so adding a view is one module
with its class and that line (imported before the config is checked; docs/architecture.md, "Extension points").

A view is a function spec -> lens (or None: the raw image), at the spec's size. A lens maps unit rays in the
camera frame (SAPIEN's axes: x forward, y left, z up) to continuous pixel coordinates and back: `rays()` (each
pixel's unit ray, and whether it lies in the field) and `project(d)`; render/fisheye.py remaps the fisheye image
into it, ground truth projects boxes with it, and the detector's `Intrinsics` read `model` (how its pixels are
laid out: "pinhole" for fx, fy, cx, cy; "cylindrical" for f pixels per radian) and fx, fy, cx, cy from it.

Plain numpy: no SAPIEN, no OpenCV.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

# View name -> fn(CameraSpec) -> lens, or None for the raw image.
VIEWS: dict[str, Callable] = {}


def register_view(name: str) -> Callable:
    """Register a view under `name`: a class with `for_spec(spec)` (or a function spec -> lens | None)."""
    def register(obj):
        VIEWS[name] = getattr(obj, "for_spec", obj)
        return obj
    return register


def grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel's centre (u, v) in continuous pixel coordinates."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    return u, v


def unit(d: np.ndarray) -> np.ndarray:
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


register_view("raw")(lambda spec: None)  # the lens's own image


@register_view("perspective")
@dataclass(frozen=True)
class Pinhole:
    """A perspective view (also a cube face). As a view it cannot hold 190 degrees: it keeps the central 120
    degrees across."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: ClassVar[str] = "pinhole"

    @classmethod
    def for_spec(cls, spec) -> "Pinhole":
        return cls.from_fovx(spec.width, spec.height, 120.0)

    @classmethod
    def from_fovx(cls, width: int, height: int, fovx: float) -> "Pinhole":
        f = width / 2.0 / math.tan(math.radians(fovx) / 2.0)
        return cls(width, height, f, f, width / 2.0, height / 2.0)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        u, v = grid(self.width, self.height)
        d = np.stack([np.ones_like(u), -(u - self.cx) / self.fx, -(v - self.cy) / self.fy], axis=-1)
        return unit(d), np.ones(u.shape, dtype=bool)

    def project(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel coordinates; rays at or behind the image plane get NaN."""
        d = np.asarray(d, dtype=float)
        x = np.where(d[..., 0] > 1e-9, d[..., 0], np.nan)
        return self.cx - self.fx * d[..., 1] / x, self.cy - self.fy * d[..., 2] / x


@register_view("cylindrical")
@dataclass(frozen=True)
class Cylindrical:
    """Columns linear in azimuth, rows linear in tan(elevation), a common undistortion for wide lenses; as a view
    it keeps the lens's whole width (up to 180 degrees)."""

    width: int
    height: int
    f: float  # pixels per radian of azimuth, and per unit of tan(elevation)
    cx: float
    cy: float
    model: ClassVar[str] = "cylindrical"

    @classmethod
    def for_spec(cls, spec) -> "Cylindrical":
        return cls.from_fovx(spec.width, spec.height, min(spec.fov, 180.0))

    @classmethod
    def from_fovx(cls, width: int, height: int, fovx: float) -> "Cylindrical":
        return cls(width, height, width / math.radians(fovx), width / 2.0, height / 2.0)

    @property
    def fx(self) -> float:
        return self.f

    @property
    def fy(self) -> float:
        return self.f

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
