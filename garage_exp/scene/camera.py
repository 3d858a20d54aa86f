"""The camera: its config check, its pose on the ego and the world -> camera transform (its lens, intrinsics and
projection are its model's lens class: scene/lenses).

Plain numpy: the renderer, ground truth and tests all place cameras with these functions, so a second renderer
only has to agree with them. Camera axes are SAPIEN's (x forward, y left, z up); a pixel (col, row) spans
[col, col+1) x [row, row+1), so the image centre is (width/2, height/2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from garage_exp.core.errors import GarageError, check_range
from garage_exp.core.plain import typed
from garage_exp.scene.description import CameraSpec, Pose
from garage_exp.scene.lenses import DEFAULT, LENSES, check_model, model_of
from garage_exp.scene.schema import CameraConf
from garage_exp.scene.views import VIEWS  # the registered views: raw, perspective, cylindrical, ...

RESOLUTION_RANGE = (16, 4096)  # pixels per side
FOVY_LEVELS = (30.0, 60.0, 90.0, 120.0)  # the research's range of forward fields of view


@dataclass(frozen=True)
class Mount:
    """A named place on the ego's body: (x, y, z) as fractions of its (length, width, height) from the centre of
    its footprint on the floor, then `clear` metres outwards so the lens sits just outside the body, and the
    direction it faces (yaw, degrees). Fractions hold for any ego model; they were read off the default ego
    (tcamrysilver, 4.77 x 1.96 x 1.50 m) and checked by casting the camera's rays at its mesh
    (tests/test_camera_mounts.py): its body shows only where a real camera at that place would see it."""

    x: float
    y: float
    z: float
    clear: tuple[float, float, float]
    yaw: float


MOUNTS = {
    # the roof's front edge (the roof drops into the windscreen ahead of it, so a level camera misses the roof)
    "roof": Mount(0.09, 0.0, 1.0, (0.0, 0.0, 0.05), 0.0),
    # behind the rear-view mirror: high on the windscreen (on its outer face; the glass is not modelled)
    "mirror": Mount(0.14, 0.0, 0.86, (0.0, 0.0, 0.03), 0.0),
    "bumper": Mount(0.5, 0.0, 0.35, (0.03, 0.0, 0.0), 0.0),  # front bumper, number-plate height
    "left_mirror": Mount(0.17, 0.5, 0.67, (0.0, 0.03, 0.0), 90.0),  # under the side mirrors, facing out
    "right_mirror": Mount(0.17, -0.5, 0.67, (0.0, -0.03, 0.0), -90.0),
    "rear": Mount(-0.5, 0.0, 0.65, (-0.03, 0.0, 0.0), 180.0),  # above the rear number plate, facing back
}


def check_camera(rig, dataset: bool = False) -> None:
    """The `camera` group: at least one camera, known mounts and lens models, sane fields of view and sizes.
    `dataset`: the job writes KITTI labels, whose calibration is a pinhole matrix; a lens camera's frames (a
    fisheye's) then have to be its perspective view."""
    if not rig.cameras:
        raise GarageError("the rig has no camera", "camera.cameras")
    if dataset and rig.view != "perspective" and any(
            not model_of(cam).pinhole_frames for cam in rig.cameras if (cam.model or DEFAULT) in LENSES):
        raise GarageError(f"dataset=true writes KITTI's pinhole calibration, which {rig.view} fisheye frames do"
                          " not have: use camera.view=perspective", "camera.view")
    for key, value in (("mount", rig.mount), ("fovy", rig.fovy), ("pitch", rig.pitch), ("z", rig.z)):
        if value is not None and len(rig.cameras) != 1:
            raise GarageError(f"camera.{key} applies to a one-camera rig; rig {rig.name} has {len(rig.cameras)}"
                              " (set it per camera in camera.cameras)", f"camera.{key}")
    if rig.view not in VIEWS:
        raise GarageError(f"unknown view {rig.view!r} ({' | '.join(VIEWS)})", "camera.view")
    for k, cam in enumerate(_effective(rig)):
        where = f"camera.cameras.{k}"
        mount = cam.mount
        if mount is not None and mount not in MOUNTS:
            key = "camera.mount" if rig.mount is not None else f"{where}.mount"
            raise GarageError(f"unknown mount {mount!r} ({' | '.join(MOUNTS)})", key)
        check_model(cam, where).check(cam, rig, where)
        for side, rig_value, value in (("width", rig.width, cam.width), ("height", rig.height, cam.height)):
            key = f"camera.{side}" if rig_value is not None else f"{where}.{side}"
            check_range(value, *RESOLUTION_RANGE, key, f"{side} {value} px")


def scored_camera(rig, wanted: str = "") -> str:
    """The camera whose frames score a case: the one it names (`case.camera`: a reversing ego's rear camera),
    else the rig's first; GarageError at `case.camera` when the rig has no camera so named."""
    names = [str(cam.name) for cam in rig.cameras]
    if not wanted:
        return names[0]
    if wanted not in names:
        raise GarageError(f"the case is scored by camera {wanted!r}; rig {rig.name} has {', '.join(names)} (pick a "
                          f"rig with a camera named {wanted!r}, or set case.camera)", "case.camera")
    return wanted


@dataclass
class Effective(CameraConf):
    """A camera as the rig makes it: its values with the rig's top-level overrides applied (see CameraRigConf),
    and the rig's `z` as metres added to its height (None: none)."""

    z_offset: float | None = None


def _effective(rig) -> list[Effective]:
    """Each camera of the rig (CameraRigConf, or a node of it) as the rig makes it (Effective)."""
    top = {key: value for key, value in (("mount", rig.mount), ("fovy", rig.fovy), ("pitch", rig.pitch),
                                         ("width", rig.width), ("height", rig.height)) if value is not None}
    return [Effective(**{**vars(typed(CameraConf, cam, f"camera.cameras.{k}")), **top, "z_offset": rig.z})
            for k, cam in enumerate(rig.cameras)]


def mount_pose(name: str, extent) -> Pose:
    """A named mount's pose on an ego of this extent (length, width, height)."""
    m = MOUNTS[name]
    length, width, height = (float(v) for v in extent)
    return Pose(m.x * length + m.clear[0], m.y * width + m.clear[1], m.z * height + m.clear[2], m.yaw)


def rig_specs(rig, ego_extent) -> list[CameraSpec]:
    """The rig's cameras, mounted on an ego of this extent (length, width, height): a named mount's pose, or
    the list's x, y, z (`rig.roof`: z counts from the ego's roof); the rig's top-level keys override."""
    roof = float(ego_extent[2]) if rig.roof else 0.0
    view = rig.view
    out = []
    for cam in _effective(rig):
        mount = cam.mount
        pose = mount_pose(mount, ego_extent) if mount else Pose(cam.x, cam.y, roof + cam.z, cam.yaw)
        if cam.z_offset is not None:
            pose = Pose(pose.x, pose.y, pose.z + float(cam.z_offset), pose.yaw)
        model = model_of(cam)
        out.append(CameraSpec(cam.name, pose, pitch=cam.pitch, fovy=cam.fovy, width=cam.width, height=cam.height,
                              model=model.model, **model.spec_fields(cam, view)))
    return out


def camera_to_world(ego: Pose, spec: CameraSpec) -> np.ndarray:
    """The camera's 4x4 pose: the ego's pose, then the mount (offset and yaw), then the pitch (positive down)."""
    mount = ego.compose(spec.mount)
    out = np.eye(4)
    out[:3, :3] = rotation(mount.yaw, spec.pitch)
    out[:3, 3] = (mount.x, mount.y, mount.z)
    return out


def rotation(yaw: float, pitch: float) -> np.ndarray:
    """3x3 rotation of a camera turned by `yaw` (degrees, left-positive, about z) and then `pitch` (degrees,
    positive looks down); the cube map's faces are turned the same way (render/fisheye.face_rotation)."""
    yaw, pitch = math.radians(yaw), math.radians(pitch)
    cz, sz, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    # A positive rotation about the camera's y (left) axis turns its x (forward) axis downwards.
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return rz @ ry


def to_camera(cam_to_world: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World points (N x 3) in the camera's frame (x: depth along the view axis)."""
    return (np.asarray(points, dtype=float).reshape(-1, 3) - cam_to_world[:3, 3]) @ cam_to_world[:3, :3]
