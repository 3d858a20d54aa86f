"""A bird's-eye view (BEV) of the floor around the ego, stitched from its fisheye cameras (inverse perspective).

Plain numpy and OpenCV, no SAPIEN. Each BEV pixel is a point of the floor (z = 0) around the ego; every fisheye
camera that sees it gives the pixel where its lens images that point, through the same lens model
(`scene/lenses/fisheye.Fisheye.project`) and the same camera pose (`scene/camera.camera_to_world`) that the renderer
and ground truth use, so the calibration is exact. `cv2.remap` then samples each camera's picture.

Orientation: the ego's forward (+x of its frame) is up in the image, its left (+y) is left; the ego's centre
(its footprint's centre on the floor) is the image centre. Pixel (col, row) spans [col, col+1) x [row, row+1).

Where several cameras see a point, the BEV takes the camera whose ray to it is closest to its optical axis (the
sharpest, least stretched view); `seams` marks the pixels where the choice changes. The floor under the ego's
body is seen by no camera (the body is in the way) and stays black. Only the floor is mapped right: anything
standing on it (a parked car, a pillar, a person) is drawn where its rays meet the floor, so it stretches away
from the camera that sees it, more the higher it is. That is what every IPM surround view does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from garage_exp.core.state import STATE
from garage_exp.core.errors import GarageError, check_range
from garage_exp.scene.camera import camera_to_world, to_camera
from garage_exp.scene.description import CameraSpec, Pose
from garage_exp.scene.lenses import camera_model, lens_of
from garage_exp.scene.schema import BevSpec

SIZE_RANGE = (2.0, 60.0)  # metres per side
MPP_RANGE = (0.005, 0.5)  # metres per pixel
MAX_PIXELS = 2000  # per side
EGO_MARGIN = 0.1  # metres added around the ego's footprint that no camera sees
OFF_IMAGE = -1.0  # cv2.remap's coordinate for "no sample" (black with BORDER_CONSTANT)


def spec_of(conf) -> BevSpec:
    """A `camera.bev` node as its dataclass (the node is the spec: scene/schema.py)."""
    return BevSpec(float(conf.length), float(conf.width), float(conf.meters_per_pixel), enabled=bool(conf.enabled))


def check_bev(conf, where: str = "camera.bev") -> None:
    check_range(conf.length, *SIZE_RANGE, f"{where}.length", f"BEV length {conf.length} m")
    check_range(conf.width, *SIZE_RANGE, f"{where}.width", f"BEV width {conf.width} m")
    check_range(conf.meters_per_pixel, *MPP_RANGE, f"{where}.meters_per_pixel",
                f"{conf.meters_per_pixel} m per BEV pixel")
    spec = spec_of(conf)
    if max(spec.size) > MAX_PIXELS:
        raise GarageError(f"the BEV would be {spec.size[0]}x{spec.size[1]} pixels (at most {MAX_PIXELS} a side): "
                          "a coarser meters_per_pixel or a smaller area", f"{where}.meters_per_pixel")


@dataclass(frozen=True)
class BevMaps:
    """Where each BEV pixel samples each camera, and which camera it takes."""

    spec: BevSpec
    cameras: tuple[str, ...]
    map_x: np.ndarray  # cameras x H x W float32, cv2.remap's convention (pixel centres at integers), -1: unseen
    map_y: np.ndarray
    owner: np.ndarray  # H x W int8: the camera the BEV takes (index into `cameras`), -1: none sees the floor there
    theta: np.ndarray  # H x W float32: the owner's ray angle from its optical axis (radians), inf where none

    @property
    def seams(self) -> np.ndarray:
        """H x W bool: pixels next to a pixel taken from another camera."""
        o = self.owner
        out = np.zeros(o.shape, dtype=bool)
        rows = (o[1:, :] != o[:-1, :]) & (o[1:, :] >= 0) & (o[:-1, :] >= 0)
        cols = (o[:, 1:] != o[:, :-1]) & (o[:, 1:] >= 0) & (o[:, :-1] >= 0)
        out[1:, :] |= rows
        out[:-1, :] |= rows
        out[:, 1:] |= cols
        out[:, :-1] |= cols
        return out

    def stitch(self, pictures: dict[str, np.ndarray]) -> np.ndarray:
        """The BEV picture from each camera's picture (same names as `cameras`, the rendered size), bilinear."""
        import cv2

        first = next(iter(pictures.values()))
        out = np.zeros(self.owner.shape + first.shape[2:], dtype=first.dtype)
        for k, name in enumerate(self.cameras):
            take = self.owner == k
            if not take.any() or name not in pictures:
                continue
            sampled = cv2.remap(pictures[name], self.map_x[k], self.map_y[k], cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            out[take] = sampled[take]
        return out


def bev_maps(cameras, spec: BevSpec, ego_extent=None) -> BevMaps:
    """The maps of a rig's fisheye cameras (CameraSpec, mounted on the ego; those whose model stitches into a
    BEV, scene/lenses) for a BEV; cached per (rig, spec, ego extent): they do not depend on where the ego
    stands."""
    fisheyes = tuple(c for c in cameras if camera_model(c.model).bev)
    if not fisheyes:
        raise GarageError("a bird's-eye view needs fisheye cameras; this rig has none", "camera.bev")
    extent = None if ego_extent is None else tuple(round(float(v), 6) for v in ego_extent)
    return _maps(fisheyes, spec, extent)


@STATE.memo("process", maxsize=8)
def _maps(cameras: tuple[CameraSpec, ...], spec: BevSpec, extent) -> BevMaps:
    w, h = spec.size
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    x, y = spec.pixel_to_ego(cols, rows)
    floor = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    map_x = np.full((len(cameras), h, w), OFF_IMAGE, dtype=np.float32)
    map_y = np.full((len(cameras), h, w), OFF_IMAGE, dtype=np.float32)
    thetas = np.full((len(cameras), h, w), np.inf)
    for k, cam in enumerate(cameras):
        pose = camera_to_world(Pose(), cam)  # the ego at the origin: maps in the ego's frame
        local = to_camera(pose, floor)
        lens = lens_of(cam)
        u, v = lens.project(local)
        theta = np.arctan2(np.hypot(local[:, 1], local[:, 2]), local[:, 0])
        ok = (theta <= lens.theta_max) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        ok &= pose[2, 3] > 0.0  # a camera at or under the floor sees none of it
        map_x[k].reshape(-1)[ok] = (u[ok] - 0.5).astype(np.float32)
        map_y[k].reshape(-1)[ok] = (v[ok] - 0.5).astype(np.float32)
        thetas[k].reshape(-1)[ok] = theta[ok]
    owner = np.argmin(thetas, axis=0).astype(np.int8)
    best = np.min(thetas, axis=0)
    owner[~np.isfinite(best)] = -1
    if extent is not None:  # under the body: the cameras see the car there, not the floor
        hl, hw = extent[0] / 2 + EGO_MARGIN, extent[1] / 2 + EGO_MARGIN
        under = (np.abs(x) <= hl) & (np.abs(y) <= hw)
        owner[under] = -1
        best = np.where(under, np.inf, best)
    for arr in (map_x, map_y, owner, best):
        arr.setflags(write=False)
    return BevMaps(spec, tuple(c.name for c in cameras), map_x, map_y, owner, best.astype(np.float32))
