"""Camera models (`camera.cameras[k].model`), one entry each: how a camera of the model is checked, which of
its config's lens fields its CameraSpec carries, and what the rest of the pipeline may ask of it.

Everything that treats cameras by their model reads it from here instead of comparing names: the config check
(scene/camera.check_camera), the specs (scene/camera.rig_specs), the renderer (CameraSpec.fisheye: drawn from
a cube map through the model's lens, render/fisheye.py), the bird's-eye view and slot cases
(run/preflight.py, slots/frames.py, the search's slots objective), the frame table's off-axis angle
(run/frames.py) and the KITTI export's pinhole calibration (check_camera with dataset=true).

What a model must provide: a pinhole model is rendered as one picture with `scene/camera.intrinsics_of`
(fx, fy, cx, cy from fovy) and projects with `scene/camera.to_pixels`; a lens model (cube_map) names `lens`, a
function spec -> lens object with `rays()` (each pixel's unit ray in the camera frame, and whether it lies in the
field) and `project(d)` (continuous pixel coordinates of rays), from which render/fisheye.cube_map makes the
faces and remaps that render it, ground truth projects boxes and slots, and render/bev.py stitches the BEV.

Adding a camera model is one `register_camera_model(CameraModel(...))` in a module of its own (its check beside
it; a function spec -> lens, named by `lens`, when it is drawn from a cube map: render/fisheye.Fisheye is one);
docs/architecture.md, "Extension points".
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from garage_exp.core.errors import GarageError, check_range

FOVY_RANGE = (1.0, 170.0)  # degrees, vertical
FISHEYE_FOV_RANGE = (60.0, 200.0)  # degrees across the image width; the lenses are about 190
NO_K = (0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class CameraModel:
    name: str
    # The camera's own lens fields: cam is its values with the rig's top-level keys applied (camera._effective),
    # rig the rig's node (to name the place of a top-level key), where the camera's place.
    check: Callable[[object, object, str], None]
    # The CameraSpec's lens fields (fov, k, view) from the camera's values and the rig's view.
    spec: Callable[[object, str], dict]
    lens: str = ""  # dotted name of spec -> lens (rays, project); "" for a pinhole model, drawn as one picture
    bev: bool = False  # its raw pictures stitch into a bird's-eye view (render/bev.py; a slot case's frames)
    # A detector's frames carry a pinhole calibration as they are (KITTI's), not only in a perspective view.
    pinhole_frames: bool = True

    @property
    def cube_map(self) -> bool:
        """Drawn from a cube map through its lens (render/fisheye.py), and so seen far off its axis (the frame
        table records the target's off-axis angle)."""
        return bool(self.lens)


def _check_pinhole(cam, rig, where: str) -> None:
    key = "camera.fovy" if rig.get("fovy") is not None else f"{where}.fovy"
    check_range(cam.fovy, *FOVY_RANGE, key, f"fovy {cam.fovy} degrees")


def _pinhole_spec(cam, view: str) -> dict:
    return {"fov": 0.0, "k": NO_K, "view": "raw"}


def _check_fisheye(cam, rig, where: str) -> None:
    check_range(cam.fov, *FISHEYE_FOV_RANGE, f"{where}.fov", f"fisheye fov {cam.fov} degrees")
    if len(cam.k) != 4:
        raise GarageError(f"a fisheye lens has 4 coefficients k1..k4, not {len(cam.k)}", f"{where}.k")
    if not _monotonic(cam.fov, cam.k):
        raise GarageError(f"coefficients {list(cam.k)} fold the image back within fov {cam.fov}", f"{where}.k")


def _monotonic(fov: float, k) -> bool:
    """Whether theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8) grows over the lens's field."""
    theta = np.linspace(0.0, math.radians(fov) / 2.0, 200)
    t2 = theta * theta
    theta_d = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
    return bool(np.all(np.diff(theta_d) > 0))


def _fisheye_spec(cam, view: str) -> dict:
    return {"fov": float(cam.fov), "k": tuple(float(v) for v in cam.k), "view": view}


MODELS: dict[str, CameraModel] = {}


def register_camera_model(model: CameraModel) -> CameraModel:
    """Register a camera model under its name (`camera.cameras[k].model`), replacing one of that name."""
    MODELS[model.name] = model
    return model


register_camera_model(CameraModel("pinhole", _check_pinhole, _pinhole_spec))
# OpenCV's Kannala-Brandt fisheye, `fov` degrees across the image width (render/fisheye.py)
register_camera_model(CameraModel("fisheye", _check_fisheye, _fisheye_spec,
                                  lens="garage_exp.render.fisheye.kannala_brandt", bev=True, pinhole_frames=False))
DEFAULT = "pinhole"


def camera_model(name: str) -> CameraModel:
    """The model a camera or spec names (check_camera has refused unknown names)."""
    return MODELS[name]


def model_of(cam) -> CameraModel:
    """A camera config node's model (its `model`, pinhole when unset)."""
    return MODELS[str(cam.get("model", DEFAULT))]


def check_model(cam, where: str) -> CameraModel:
    """The camera's model by name, or a GarageError at `where.model`."""
    name = str(cam.get("model", DEFAULT))
    if name not in MODELS:
        raise GarageError(f"unknown camera model {name!r} ({' | '.join(MODELS)})", f"{where}.model")
    return MODELS[name]


def rig_has(rig, what: str) -> bool:
    """Whether any camera of the rig (its config node) has the model property `what` (bev, cube_map)."""
    return any(getattr(MODELS.get(str(cam.get("model", DEFAULT))), what, False) for cam in rig.cameras)
