"""OpenCV's fisheye lens (Kannala-Brandt with four coefficients, `cv2.fisheye`), `fov` degrees across the image
width (the image circle is cropped at the top and bottom, as in WoodScape), drawn from a cube map.

theta is a ray's angle from the optical axis, theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
k4 theta^8), and the pixel lies theta_d * f from the centre in the ray's direction. OpenCV's own
`cv2.fisheye.projectPoints` divides by the depth first and so folds rays beyond 90 degrees back into the image; a
190-degree lens needs them, so the projection is written out here (tests check it against OpenCV's within 90
degrees).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from garage_exp.core.errors import GarageError, check_range
from garage_exp.scene.lenses.base import Lens, SquarePixels, grid, register_lens, unit

FISHEYE_FOV_RANGE = (60.0, 200.0)  # degrees across the image width; the lenses are about 190


def kannala_brandt(theta, k):
    """theta_d of angles theta off the axis (numpy arrays or floats)."""
    k1, k2, k3, k4 = k
    t2 = theta * theta
    return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


@register_lens("fisheye")
@dataclass(frozen=True)
class Fisheye(SquarePixels, Lens):
    fov: float  # degrees across the image width
    k: tuple[float, float, float, float]
    bev = True
    pinhole_frames = False

    @classmethod
    def check(cls, cam, rig, where: str) -> None:
        check_range(cam.fov, *FISHEYE_FOV_RANGE, f"{where}.fov", f"fisheye fov {cam.fov} degrees")
        if len(cam.k) != 4:
            raise GarageError(f"a fisheye lens has 4 coefficients k1..k4, not {len(cam.k)}", f"{where}.k")
        # theta_d must grow over the lens's field, or the image folds back on itself
        theta = np.linspace(0.0, math.radians(cam.fov) / 2.0, 200)
        if not np.all(np.diff(kannala_brandt(theta, cam.k)) > 0):
            raise GarageError(f"coefficients {list(cam.k)} fold the image back within fov {cam.fov}", f"{where}.k")

    @classmethod
    def spec_fields(cls, cam, view: str) -> dict:
        return {"fov": float(cam.fov), "k": tuple(float(v) for v in cam.k), "view": view}

    @classmethod
    def of(cls, spec) -> Fisheye:
        return cls(spec.width, spec.height, spec.fov, tuple(spec.k))

    @property
    def theta_max(self) -> float:
        return math.radians(self.fov) / 2.0

    @property
    def f(self) -> float:
        return self.width / 2.0 / float(self.distort(np.array(self.theta_max)))

    @property
    def cx(self) -> float:
        return self.width / 2.0

    @property
    def cy(self) -> float:
        return self.height / 2.0

    def distort(self, theta: np.ndarray) -> np.ndarray:
        return kannala_brandt(theta, self.k)

    def undistort(self, theta_d: np.ndarray) -> np.ndarray:
        """theta from theta_d by Newton's method (as cv2.fisheye.undistortPoints does)."""
        k1, k2, k3, k4 = self.k
        theta = np.array(theta_d, dtype=float)
        for _ in range(12):
            t2 = theta * theta
            g = self.distort(theta) - theta_d
            dg = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = theta - g / dg
        return theta

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit rays of every pixel and whether it lies within the lens's field (theta <= fov / 2)."""
        u, v = grid(self.width, self.height)
        a, b = (u - self.cx) / self.f, (v - self.cy) / self.f  # right, down
        theta_d = np.hypot(a, b)
        theta = self.undistort(np.minimum(theta_d, float(self.distort(np.array(self.theta_max)))))
        inside = theta_d <= float(self.distort(np.array(self.theta_max)))
        scale = np.where(theta_d > 1e-12, np.sin(theta) / np.where(theta_d > 1e-12, theta_d, 1.0), 1.0)
        d = np.stack([np.cos(theta), -a * scale, -b * scale], axis=-1)
        return unit(d), inside

    def project(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel coordinates of rays in any direction (beyond fov / 2 they land outside the image
        circle; theta_d is continued linearly there so that folded coefficients never bring them back)."""
        d = np.asarray(d, dtype=float)
        right, down = -d[..., 1], -d[..., 2]
        r = np.hypot(right, down)
        theta = np.arctan2(r, d[..., 0])
        edge = self.theta_max
        slope = float((self.distort(np.array(edge + 1e-4)) - self.distort(np.array(edge - 1e-4))) / 2e-4)
        theta_d = np.where(theta <= edge, self.distort(np.minimum(theta, edge)),
                           float(self.distort(np.array(edge))) + max(slope, 1e-3) * (theta - edge))
        scale = np.where(r > 1e-12, theta_d / np.where(r > 1e-12, r, 1.0), 0.0)
        return self.cx + self.f * right * scale, self.cy + self.f * down * scale

    def in_field(self, rays: np.ndarray) -> np.ndarray:
        return np.arccos(np.clip(rays[..., 0], -1.0, 1.0)) <= self.theta_max
