"""Fisheye cameras from a cube map: OpenCV's fisheye lens model, the cube faces it needs and the remaps.

Plain numpy and OpenCV, no SAPIEN: the backend renders the faces this module asks for, and ground truth and the
tests project with the same lenses.

Lenses map unit ray directions in the camera frame (SAPIEN's axes: x forward, y left, z up) to continuous pixel
coordinates (u, v) with the project's convention (pixel (col, row) spans [col, col+1) x [row, row+1)) and back.
- `Fisheye`: OpenCV's fisheye model (Kannala-Brandt with four coefficients, `cv2.fisheye`): theta is the ray's
  angle from the optical axis, theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8), and the
  pixel lies theta_d * f from the centre in the ray's direction. OpenCV's own `cv2.fisheye.projectPoints` divides
  by the depth first and so folds rays beyond 90 degrees back into the image; a 190-degree lens needs them, so
  the projection is written out here (tests check it against OpenCV's within 90 degrees). f is chosen so that
  the lens's `fov` spans the image width (the image circle is cropped at the top and bottom, as in WoodScape).
- `Pinhole`: a perspective view (a cube face, or a view undistorted from a fisheye image).
- `Cylindrical`: columns linear in azimuth, rows linear in tan(elevation), a common undistortion for wide lenses.

A cube map: the faces are 90-degree pinhole views at the camera's centre (front, left, right, up, down, back);
only the faces some fisheye pixel looks into are rendered, each at the size that gives every fisheye pixel's
footprint at least one face pixel (the 99th percentile over the face's fisheye pixels), plus a pixel of margin on
every side so that bilinear sampling at a face's edge stays within the face. Of each face only the rectangle
the lens samples is rendered (`crops`: an off-centre pinhole; a 4:3 image cuts the image circle at the top and
bottom, so the up and down faces need a band of rows): two thirds of the full faces' pixels for a 190-degree
640x480 lens. The crops are stacked in one atlas image, so colour is one `cv2.remap` (bilinear) and ids and
silhouettes one nearest-neighbour lookup.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# The views a detector may get instead of the raw image live with the scene's camera models (scene/views.py,
# registered there); they are lenses like the ones here.
from garage_exp.scene.views import VIEWS, Cylindrical, Pinhole, grid as _grid, unit as _unit  # noqa: F401

PAD = 1  # face pixels of margin on every side (bilinear sampling at a face's edge)
MIN_FACE = 16  # pixels per face side at least
FACE_QUANTILE = 99.0  # per cent of a face's fisheye pixels whose footprint gets at least one face pixel
# Each face as a rotation of the camera: yaw (left-positive) then pitch (positive looks down), degrees.
FACES = {"front": (0.0, 0.0), "left": (90.0, 0.0), "right": (-90.0, 0.0), "up": (0.0, -90.0),
         "down": (0.0, 90.0), "back": (180.0, 0.0)}


def face_rotation(name: str) -> np.ndarray:
    """3x3 rotation from a face camera's frame to the camera's frame (same convention as camera_to_world)."""
    yaw, pitch = (math.radians(a) for a in FACES[name])
    cz, sz, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return rz @ ry


@dataclass(frozen=True)
class Fisheye:
    width: int
    height: int
    fov: float  # degrees across the image width
    k: tuple[float, float, float, float]

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

    @property
    def camera_matrix(self) -> np.ndarray:
        """K for cv2.fisheye in its pixel convention (pixel centres at integers)."""
        return np.array([[self.f, 0.0, self.cx - 0.5], [0.0, self.f, self.cy - 0.5], [0.0, 0.0, 1.0]])

    def distort(self, theta: np.ndarray) -> np.ndarray:
        k1, k2, k3, k4 = self.k
        t2 = theta * theta
        return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def undistort(self, theta_d: np.ndarray) -> np.ndarray:
        """theta from theta_d by Newton's method (as cv2.fisheye.undistortPoints does)."""
        k1, k2, k3, k4 = self.k
        theta = np.array(theta_d, dtype=float)
        for _ in range(12):
            t2 = theta * theta
            g = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
            dg = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = theta - g / dg
        return theta

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit rays of every pixel and whether it lies within the lens's field (theta <= fov / 2)."""
        u, v = _grid(self.width, self.height)
        a, b = (u - self.cx) / self.f, (v - self.cy) / self.f  # right, down
        theta_d = np.hypot(a, b)
        theta = self.undistort(np.minimum(theta_d, float(self.distort(np.array(self.theta_max)))))
        inside = theta_d <= float(self.distort(np.array(self.theta_max)))
        scale = np.where(theta_d > 1e-12, np.sin(theta) / np.where(theta_d > 1e-12, theta_d, 1.0), 1.0)
        d = np.stack([np.cos(theta), -a * scale, -b * scale], axis=-1)
        return _unit(d), inside

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


def kannala_brandt(spec) -> Fisheye:
    """The lens of a camera spec of the fisheye model (scene/lenses.py)."""
    return Fisheye(spec.width, spec.height, spec.fov, tuple(spec.k))


def lens_of(spec) -> Fisheye:
    """The lens a cube-mapped camera's model names (scene/lenses.py: `lens`)."""
    from garage_exp.core.plugins import resolve
    from garage_exp.scene.lenses import camera_model

    model = camera_model(spec.model)
    return resolve(model.lens, "a camera lens", f"camera model {model.name}")(spec)


def view_lens(spec):
    """The undistorted view a fisheye camera's detector gets (`spec.view`, a registered view: scene/views.py),
    None for the raw image."""
    return VIEWS[spec.view](spec)


@dataclass
class CubeMap:
    """The faces a fisheye camera needs, their sizes, and where each fisheye pixel samples the face atlas."""

    faces: list[str]
    sizes: list[int]  # pixels per side of the whole face, margin included (its focal length is (size - 2) / 2)
    crops: list[tuple[int, int, int, int]]  # the rectangle of each face that is rendered: x0, y0, width, height
    offsets: list[int]  # row of each crop's top in the atlas
    map_x: np.ndarray  # HxW float32, atlas column of each fisheye pixel (cv2.remap's convention), -1 outside
    map_y: np.ndarray
    flat: np.ndarray  # HxW int64, the nearest atlas pixel's flat index, -1 outside the lens's field

    @property
    def atlas_shape(self) -> tuple[int, int]:
        return sum(c[3] for c in self.crops), max(c[2] for c in self.crops)

    @property
    def rendered_pixels(self) -> int:
        return sum(c[2] * c[3] for c in self.crops)

    def face_fovy(self, k: int) -> float:
        """The face camera's field of view in degrees: 90 plus its margin."""
        n = self.sizes[k] - 2 * PAD
        return math.degrees(2.0 * math.atan((n / 2.0 + PAD) / (n / 2.0)))

    def atlas(self, pictures: list[np.ndarray], fill=0) -> np.ndarray:
        """The faces' pictures (their crops, in `faces` order) stacked into one atlas image."""
        h, w = self.atlas_shape
        first = pictures[0]
        out = np.full((h, w, *first.shape[2:]), fill, dtype=first.dtype)
        for pic, top in zip(pictures, self.offsets):
            out[top:top + pic.shape[0], :pic.shape[1]] = pic
        return out

    def remap_colour(self, atlas: np.ndarray) -> np.ndarray:
        return remap_bilinear(atlas, self.map_x, self.map_y)

    def remap_nearest(self, atlas: np.ndarray, fill=0) -> np.ndarray:
        return lookup(atlas, self.flat, fill)


def remap_bilinear(picture: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """cv2.remap with bilinear sampling; pixels mapped outside the picture (-1) come out black."""
    import cv2

    return cv2.remap(picture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def lookup(picture: np.ndarray, flat: np.ndarray, fill=0) -> np.ndarray:
    """Nearest-neighbour remap: picture read at flat pixel indices; -1 gives `fill`."""
    out = picture.reshape(-1, *picture.shape[2:])[np.maximum(flat, 0)]
    out[flat < 0] = fill
    return out


def cube_map(lens: Fisheye) -> CubeMap:
    """Which faces the lens sees, the size each needs, and the lookups from fisheye pixels into the atlas."""
    rays, inside = lens.rays()
    rays = rays.astype(float)
    names = list(FACES)
    rots = [face_rotation(n) for n in names]
    # A ray belongs to the face whose axis it is closest to; in that face's frame |y|, |z| <= x.
    along = np.stack([rays @ r[:, 0] for r in rots], axis=-1)
    face_of = np.argmax(along, axis=-1)
    face_of[~inside] = -1
    # Face-plane coordinates (tan of the angles) of every ray in its face, and their spacing between
    # neighbouring fisheye pixels: the area a fisheye pixel covers on its face.
    coords = np.zeros(rays.shape[:2] + (2,))
    for k, rot in enumerate(rots):
        sel = face_of == k
        local = rays[sel] @ rot
        coords[sel] = np.stack([-local[:, 1] / local[:, 0], -local[:, 2] / local[:, 0]], axis=-1)
    du = np.gradient(coords, axis=1)
    dv = np.gradient(coords, axis=0)
    area = np.abs(du[..., 0] * dv[..., 1] - du[..., 1] * dv[..., 0])
    same = np.zeros(face_of.shape, dtype=bool)  # neighbours on the same face (gradients across a seam lie)
    same[1:-1, 1:-1] = ((face_of[1:-1, 1:-1] == face_of[:-2, 1:-1]) & (face_of[1:-1, 1:-1] == face_of[2:, 1:-1])
                        & (face_of[1:-1, 1:-1] == face_of[1:-1, :-2]) & (face_of[1:-1, 1:-1] == face_of[1:-1, 2:]))
    faces, sizes, crops, offsets = [], [], [], []
    map_x = np.full(face_of.shape, -1.0, dtype=np.float32)
    map_y = np.full(face_of.shape, -1.0, dtype=np.float32)
    flat = np.full(face_of.shape, -1, dtype=np.int64)
    placed = []
    top = 0
    for k, name in enumerate(names):
        sel = face_of == k
        if not sel.any():
            continue
        good = sel & same & (area > 0)
        # A face of n pixels spans 2 face-plane units: a fisheye pixel covering `area` gets n^2 area / 4 of them.
        need = 2.0 / np.sqrt(np.percentile(area[good], 100.0 - FACE_QUANTILE)) if good.any() else MIN_FACE
        n = int(max(MIN_FACE, math.ceil(need)))
        n += n % 2
        size = n + 2 * PAD
        # face pixel coordinates (continuous) of the fisheye pixels it serves, and the rectangle they need
        # (bilinear sampling reads the pixel beyond: a pixel of margin, within the face)
        u = size_centre(n) + n / 2.0 * coords[sel][:, 0]
        v = size_centre(n) + n / 2.0 * coords[sel][:, 1]
        x0, y0 = max(int(np.floor(u.min() - 0.5)) - PAD, 0), max(int(np.floor(v.min() - 0.5)) - PAD, 0)
        x1 = min(int(np.floor(u.max() - 0.5)) + 1 + PAD, size - 1)
        y1 = min(int(np.floor(v.max() - 0.5)) + 1 + PAD, size - 1)
        crop = (x0, y0, x1 - x0 + 1, y1 - y0 + 1)
        faces.append(name)
        sizes.append(size)
        crops.append(crop)
        offsets.append(top)
        placed.append((sel, u - x0, v - y0, crop, top))
        top += crop[3]
    width = max(c[2] for c in crops)
    for sel, u, v, crop, top in placed:
        map_x[sel] = (u - 0.5).astype(np.float32)  # cv2.remap's convention: pixel centres at integers
        map_y[sel] = (top + v - 0.5).astype(np.float32)
        col = np.clip(np.floor(u), 0, crop[2] - 1).astype(np.int64)
        row = np.clip(np.floor(v), 0, crop[3] - 1).astype(np.int64)
        flat[sel] = (top + row) * width + col
    return CubeMap(faces, sizes, crops, offsets, map_x, map_y, flat)


def size_centre(n: int) -> float:
    """The centre of a face of n pixels plus its margins, in continuous pixel coordinates."""
    return n / 2.0 + PAD


def view_remap(source, target) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """cv2.remap maps (float32) and the nearest source pixel's flat index (-1 outside) for a view `target`
    undistorted from an image of lens `source` (a fisheye)."""
    rays, _ = target.rays()
    u, v = source.project(rays)
    ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u < source.width) & (v >= 0) & (v < source.height)
    if isinstance(source, Fisheye):
        ok &= np.arccos(np.clip(rays[..., 0], -1.0, 1.0)) <= source.theta_max
    map_x = np.where(ok, u - 0.5, -1.0).astype(np.float32)
    map_y = np.where(ok, v - 0.5, -1.0).astype(np.float32)
    col = np.clip(np.floor(np.nan_to_num(u)), 0, source.width - 1).astype(np.int64)
    row = np.clip(np.floor(np.nan_to_num(v)), 0, source.height - 1).astype(np.int64)
    flat = np.where(ok, row * source.width + col, -1)
    return map_x, map_y, flat
