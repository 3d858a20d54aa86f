"""Lenses, one class per camera model, each in a module of its own and registered beside itself
(`@register_lens(NAME)`, base.py): its parameters, its config check and CameraSpec fields, its rays and
projection, and its intrinsics (fx, fy, cx, cy, the camera matrix K). The one place anything asks what a camera
model is or how it images the world: the config check (scene/camera.check_camera), the specs
(scene/camera.rig_specs), the renderer (one picture for a `perspective` lens, else a cube map through the lens:
render/fisheye.py), ground truth, the bird's-eye view (`bev`), the slot cases, the frame table's off-axis angle
and the KITTI export's calibration (`pinhole_frames`), and the detector (the lens of the picture it gets:
scene/views.picture_lens).

Shipped: `pinhole` (pinhole.py), `fisheye` (OpenCV's Kannala-Brandt, fisheye.py) and `cylindrical` (the layout
of a view only, cylindrical.py). Plain numpy: no SAPIEN, no OpenCV.
"""

from garage_exp.scene.lenses.base import (DEFAULT, LENSES, NO_K, Lens, camera_model, check_model, lens_of,
                                          model_of, register_lens, rig_has)
# in the order messages list the models: pinhole (the default) first
from garage_exp.scene.lenses.pinhole import FOVY_RANGE, Pinhole  # isort: skip
from garage_exp.scene.lenses.fisheye import FISHEYE_FOV_RANGE, Fisheye  # isort: skip
from garage_exp.scene.lenses.cylindrical import Cylindrical  # isort: skip

__all__ = ["DEFAULT", "LENSES", "NO_K", "Lens", "camera_model", "check_model", "lens_of", "model_of",
           "register_lens", "rig_has", "Cylindrical", "FISHEYE_FOV_RANGE", "Fisheye", "FOVY_RANGE", "Pinhole"]
