"""What a lens is, and the registry of lenses (`camera.cameras[k].model` names one).

A lens is a frozen dataclass that owns everything about one camera model: its parameters (its fields), how a
camera config of the model is checked (`check`) and which lens fields its CameraSpec carries (`spec_fields`), the
lens of a spec (`of`), its rays (`rays()`: each pixel's unit ray in the camera frame and whether it lies in the
field), its projection (`project(d)`: continuous pixel coordinates of directions) and its intrinsics (`fx`, `fy`,
`cx`, `cy`, the camera matrix `K`). Camera axes are SAPIEN's (x forward, y left, z up); a pixel (col, row) spans
[col, col+1) x [row, row+1), so the image centre is (width/2, height/2) and `K` is in that convention (OpenCV puts
pixel centres at integers: subtract 0.5 from its principal point).

Adding a lens is one module with its class and `@register_lens("NAME")` above it (docs/architecture.md,
"Extension points"): the config check, the specs, the renderer (a cube map through `rays`/`project` unless the
lens is `perspective`), ground truth, the BEV and the detector all read the class.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from garage_exp.core.errors import GarageError

NO_K = (0.0, 0.0, 0.0, 0.0)
DEFAULT = "pinhole"

# Lens name (a camera's `model`) -> its class.
LENSES: dict[str, type[Lens]] = {}


def register_lens(name: str) -> Callable:
    """Register the decorated lens class under `name` (replacing one of that name); its `model` is the name."""
    def register(cls):
        cls.model = name
        LENSES[name] = cls
        return cls
    return register


@dataclass(frozen=True)
class Lens:
    """One camera model's lens at one image size (see the module)."""

    width: int
    height: int
    # Each lens has fx, fy (pixels per unit of its image coordinate) and cx, cy (its centre in pixels), as fields or
    # properties; `K` is made of them. A perspective lens also has `pixels(local, depth=None)`: camera-frame points
    # divided by their depth, with no near plane (ground truth clips boxes at the near plane first).

    model: ClassVar[str] = ""  # its registered name (set by register_lens)
    # A camera may be of this model (`camera.cameras[k].model`); False: the layout of a view only (scene/views.py).
    camera_model: ClassVar[bool] = True
    # A central projection onto a plane (a pinhole): drawn as one picture, nothing behind its plane is seen.
    # Otherwise the camera is drawn from a cube map through its rays (render/fisheye.py) and seen far off its axis.
    perspective: ClassVar[bool] = False
    bev: ClassVar[bool] = False  # its raw pictures stitch into a bird's-eye view (render/bev.py; slot cases)
    # A detector's frames carry a pinhole calibration as they are (KITTI's), not only in a perspective view.
    pinhole_frames: ClassVar[bool] = True

    @classmethod
    def check(cls, cam, rig, where: str) -> None:
        """Refuse a camera config of this model (`cam`: its values with the rig's top-level keys applied, `rig`:
        the rig's node, to name the place of a top-level key) with a GarageError at its place."""

    @classmethod
    def spec_fields(cls, cam, view: str) -> dict:
        """The CameraSpec's lens fields (fov, k, view) from the camera's values and the rig's view."""
        return {"fov": 0.0, "k": NO_K, "view": "raw"}

    @classmethod
    def of(cls, spec) -> Lens:
        """The lens of a camera spec (scene.description.CameraSpec) of this model."""
        raise NotImplementedError(f"lens {cls.model!r} cannot be made from a camera spec")

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the camera matrix's usual name
        """The 3x3 camera matrix (pixel (col, row) spans [col, col+1): OpenCV's principal point is 0.5 less)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def matrix(self) -> np.ndarray:
        """K by the name users' `callable:` detectors read before lenses owned it (detect.base.Intrinsics.matrix):
        their files keep working."""
        return self.K

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit rays (HxWx3) of every pixel's centre, and whether each lies within the lens's field (HxW)."""
        raise NotImplementedError

    def project(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel coordinates (u: column, v: row) of camera-frame directions (...x3); NaN where the lens
        has none."""
        raise NotImplementedError

    def in_field(self, rays: np.ndarray) -> np.ndarray:
        """Whether unit rays lie within the lens's field (all of them, unless the lens says otherwise)."""
        return np.ones(np.shape(rays)[:-1], dtype=bool)


class SquarePixels:
    """A lens with one focal length `f` (pixels per unit of its image coordinate) along both axes."""

    @property
    def fx(self) -> float:
        return self.f

    @property
    def fy(self) -> float:
        return self.f


def grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel's centre (u, v) in continuous pixel coordinates."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    return u, v


def unit(d: np.ndarray) -> np.ndarray:
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def camera_model(name: str) -> type[Lens]:
    """The lens class a camera or spec names (check_camera has refused unknown names)."""
    return LENSES[name]


def model_of(cam) -> type[Lens]:
    """A camera config node's lens class (its `model`, pinhole when unset)."""
    return LENSES[str(cam.model or DEFAULT)]


def check_model(cam, where: str) -> type[Lens]:
    """The camera's lens class by name, or a GarageError at `where.model`."""
    name = str(cam.model or DEFAULT)
    models = [n for n, cls in LENSES.items() if cls.camera_model]
    if name not in models:
        raise GarageError(f"unknown camera model {name!r} ({' | '.join(models)})", f"{where}.model")
    return LENSES[name]


def rig_has(rig, what: str) -> bool:
    """Whether any camera of the rig (its config node) has the lens property `what` (bev, ...)."""
    return any(getattr(LENSES.get(str(cam.model or DEFAULT)), what, False) for cam in rig.cameras)


def lens_of(spec) -> Lens:
    """A camera spec's own lens (its model's, at its size)."""
    return LENSES[spec.model].of(spec)
