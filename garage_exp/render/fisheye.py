"""Lens cameras (a fisheye) from a cube map: the cube faces a lens needs and the remaps from them.

Plain numpy and OpenCV, no SAPIEN: the backend renders the faces this module asks for. The lenses themselves
(their rays, projection and intrinsics) are scene/lenses'; a lens is drawn here through its `rays()`, and a view
undistorted from its image through the view's `rays()` and the lens's `project(d)`.

A cube map: the faces are 90-degree pinhole views at the camera's centre (front, left, right, up, down, back);
only the faces some fisheye pixel looks into are rendered, each at the size that gives every fisheye pixel's
footprint at least one face pixel (the 99th percentile over the face's fisheye pixels), plus a pixel of margin on
every side so that bilinear sampling at a face's edge stays within the face. Of each face only the rectangle
the lens samples is rendered (`crops`: an off-centre pinhole; a 4:3 image cuts the image circle at the top and
bottom, so the up and down faces need a band of rows): two thirds of the full faces' pixels for a 190-degree
640x480 lens. The crops are stacked in one atlas image, so colour is one `cv2.remap` (bilinear) and ids and
silhouettes one nearest-neighbour lookup.

The remaps take a numpy picture (HxW...) or a torch batch (N, H, W, ...) where it lies (the GPU path's pictures):
ids by the same lookup (exact), colour through `grid_sample` instead of `cv2.remap` (within one 8-bit level:
OpenCV quantises each sample's position to 1/32 pixel, grid_sample does not; tests/test_fisheye_torch.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from garage_exp.scene.camera import rotation
from garage_exp.scene.lenses import Lens

PAD = 1  # face pixels of margin on every side (bilinear sampling at a face's edge)
MIN_FACE = 16  # pixels per face side at least
FACE_QUANTILE = 99.0  # per cent of a face's fisheye pixels whose footprint gets at least one face pixel
# Each face as a rotation of the camera: yaw (left-positive) then pitch (positive looks down), degrees.
FACES = {"front": (0.0, 0.0), "left": (90.0, 0.0), "right": (-90.0, 0.0), "up": (0.0, -90.0),
         "down": (0.0, 90.0), "back": (180.0, 0.0)}


def face_rotation(name: str) -> np.ndarray:
    """3x3 rotation from a face camera's frame to the camera's frame (a camera's rotation: scene/camera.py)."""
    return rotation(*FACES[name])


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
    grids: dict = field(default_factory=dict, repr=False, compare=False)  # device -> grid_sample's grid (torch)

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

    def remap_colour(self, atlas):
        """The fisheye picture(s) from an atlas (numpy) or a batch of atlases (torch)."""
        if not is_torch(atlas):
            return remap_bilinear(atlas, self.map_x, self.map_y)
        if atlas.device not in self.grids:  # made once per device: the maps do not change
            h, w = self.atlas_shape
            self.grids[atlas.device] = sampling_grid(self.map_x, self.map_y, w, h, atlas.device)
        return grid_sample(atlas, self.grids[atlas.device])

    def remap_nearest(self, atlas: np.ndarray, fill=0) -> np.ndarray:
        return lookup(atlas, self.flat, fill)


def is_torch(pictures) -> bool:
    """A torch tensor (without importing torch where nobody made one)."""
    return type(pictures).__module__.startswith("torch")


def remap_bilinear(picture, map_x: np.ndarray, map_y: np.ndarray):
    """Bilinear sampling at cv2.remap's maps (pixel centres at integers); pixels mapped outside the picture (-1)
    come out black. A numpy picture through cv2.remap, a torch batch through grid_sample."""
    if is_torch(picture):
        h, w = picture.shape[1:3]
        return grid_sample(picture, sampling_grid(map_x, map_y, w, h, picture.device))
    import cv2

    return cv2.remap(picture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def sampling_grid(map_x: np.ndarray, map_y: np.ndarray, width: int, height: int, device="cpu"):
    """cv2.remap's maps as grid_sample's (1, h, w, 2) grid over a width x height picture (align_corners=True: -1
    and 1 are the centres of the first and last pixels)."""
    import torch

    gx = torch.from_numpy(np.asarray(map_x, np.float32)) * (2.0 / max(width - 1, 1)) - 1.0
    gy = torch.from_numpy(np.asarray(map_y, np.float32)) * (2.0 / max(height - 1, 1)) - 1.0
    return torch.stack([gx, gy], dim=-1)[None].to(device)


def grid_sample(pictures, grid):
    """(N, H, W, C) torch pictures (uint8 or float) sampled at `grid` (`sampling_grid`): (N, h, w, C) of the same
    dtype (uint8 rounded to nearest), black outside."""
    import torch
    import torch.nn.functional as F

    x = pictures.permute(0, 3, 1, 2).float()
    out = F.grid_sample(x, grid.expand(len(x), -1, -1, -1), mode="bilinear", padding_mode="zeros",
                        align_corners=True).permute(0, 2, 3, 1)
    if pictures.dtype == torch.uint8:
        return out.round().clamp(0, 255).to(torch.uint8)
    return out.to(pictures.dtype)


def lookup(picture, flat, fill=0):
    """Nearest-neighbour remap: a picture read at flat pixel indices (an h x w array; -1 gives `fill`). numpy
    (one HxW... picture) and torch (a batch, N x H x W x ..., on any device) alike."""
    lead = 0
    if is_torch(picture):
        import torch

        flat, lead = torch.as_tensor(flat, device=picture.device), 1
    src = picture.reshape(*picture.shape[:lead], -1, *picture.shape[lead + 2:])
    batch = (slice(None),) * lead
    out = src[batch + (flat.clip(min=0),)]
    out[batch + (flat < 0,)] = fill
    return out


def cube_map(lens: Lens) -> CubeMap:
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
    ok &= source.in_field(rays)
    map_x = np.where(ok, u - 0.5, -1.0).astype(np.float32)
    map_y = np.where(ok, v - 0.5, -1.0).astype(np.float32)
    col = np.clip(np.floor(np.nan_to_num(u)), 0, source.width - 1).astype(np.int64)
    row = np.clip(np.floor(np.nan_to_num(v)), 0, source.height - 1).astype(np.int64)
    flat = np.where(ok, row * source.width + col, -1)
    return map_x, map_y, flat
