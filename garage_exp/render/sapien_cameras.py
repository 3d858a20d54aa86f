"""SAPIEN cameras for a scene's camera specs: a lit camera and an ids-only twin per spec, the cube faces of a
fisheye, and taking their pictures.

Silhouettes: the twin renders ids only, with our own shader pack (render/shaders/ids). SAPIEN's "minimal" pack,
which it replaces, still lit every pixel from the shadow-casting lamps and rendered their shadow maps; the ids
pack keeps its vertex stage and its discard of a transparent texel and drops the rest: the same pixels and ids
(tests/test_render.py), a silhouette render's CPU about halved (docs/performance.md). A fisheye camera has no
picture of its own: its cube faces (render/fisheye.py) are pinhole cameras whose pictures are remapped.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from garage_exp.render.fisheye import CubeMap, cube_map, face_rotation, view_remap
from garage_exp.scene.description import CameraSpec
from garage_exp.scene.lenses import Lens, Pinhole, lens_of
from garage_exp.scene.views import view_lens


@dataclass
class SapienCamera:
    spec: CameraSpec
    component: object  # sapien.render.RenderCameraComponent with the default (lit) shader
    silhouette: object  # the same camera with the ids-only shader pack (shaders/ids)
    # A fisheye camera has no picture of its own: its cube faces (rotation in the camera's frame, a pinhole
    # SapienCamera) are rendered and remapped (render/fisheye.py); `view` undistorts the result for the detector.
    faces: list[tuple[np.ndarray, "SapienCamera"]] | None = None
    crop: tuple[int, int, int, int] | None = None  # a cube face's rendered rectangle (x0, y0, w, h); spec: whole face
    cube: CubeMap | None = None
    lens: Lens | None = None  # the lens drawn from the cube map
    view: tuple | None = None  # (view lens, cv2 map_x, map_y, nearest flat index) or None for the raw image

    def pinholes(self) -> list["SapienCamera"]:
        """The SAPIEN cameras this one is made of: its cube faces, or itself."""
        return [face for _, face in self.faces] if self.faces else [self]

    def place(self, pose: np.ndarray) -> None:
        """Put the camera and its silhouette twin at a 4x4 camera-to-world pose."""
        import sapien

        self.component.entity.set_pose(sapien.Pose(pose))
        self.silhouette.entity.set_pose(sapien.Pose(pose))


def add_camera(sapien_scene, spec: CameraSpec) -> SapienCamera:
    """The SAPIEN camera(s) for one spec: a pinhole camera, or a fisheye's cube faces."""
    return fisheye_camera(sapien_scene, spec) if spec.fisheye else pinhole_camera(sapien_scene, spec)


def pinhole_camera(sapien_scene, spec: CameraSpec, crop: tuple[int, int, int, int] | None = None) -> SapienCamera:
    """A camera and its silhouette twin; `crop` renders only that rectangle of the spec's image (an
    off-centre pinhole with the spec's focal length), for cube faces."""
    import sapien
    import sapien.render as sr

    width, height = (crop[2], crop[3]) if crop else (spec.width, spec.height)
    component = sapien_scene.add_camera(spec.name, width, height, math.radians(spec.fovy), spec.near, spec.far)
    silhouette = sr.RenderCameraComponent(width, height, ids_shader_dir())
    silhouette.set_fovy(math.radians(spec.fovy), compute_x=True)
    silhouette.near, silhouette.far = spec.near, spec.far
    if crop:
        face = Pinhole.of(spec)
        for cam in (component, silhouette):
            cam.set_perspective_parameters(spec.near, spec.far, face.fx, face.fy, face.cx - crop[0], face.cy - crop[1],
                                           0.0)
    mount = sapien.Entity()
    mount.name = f"{spec.name}:silhouette"
    mount.add_component(silhouette)
    sapien_scene.add_entity(mount)
    return SapienCamera(spec, component, silhouette, crop=crop)


def reconfigured(cam: SapienCamera, spec: CameraSpec) -> SapienCamera | None:
    """`cam` (both its SAPIEN cameras) set to `spec`'s field of view and clip planes, as `pinhole_camera` makes a
    new one; None when only a new camera fits: a fisheye or a cube face, or another image size. A wide space draws
    the field of view per scenario, and removing a camera's two entities from the scene cost ~12 ms a scenario."""
    if cam.faces or cam.crop or spec.fisheye or (cam.spec.width, cam.spec.height) != (spec.width, spec.height):
        return None
    for component in (cam.component, cam.silhouette):
        component.set_fovy(math.radians(spec.fovy), compute_x=True)
        component.near, component.far = spec.near, spec.far
    return SapienCamera(spec, cam.component, cam.silhouette)


def fisheye_camera(sapien_scene, spec: CameraSpec) -> SapienCamera:
    """The cube faces the lens sees, each a pinhole camera at the size the fisheye needs (render/fisheye.py)."""
    lens = lens_of(spec)
    cube = cube_map(lens)
    faces = []
    for k, face in enumerate(cube.faces):
        size = cube.sizes[k]
        face_spec = CameraSpec(f"{spec.name}:{face}", spec.mount, pitch=spec.pitch, fovy=cube.face_fovy(k),
                               width=size, height=size, near=spec.near, far=spec.far)
        rot = np.eye(4)
        rot[:3, :3] = face_rotation(face)
        faces.append((rot, pinhole_camera(sapien_scene, face_spec, cube.crops[k])))
    target = view_lens(spec)
    view = (target, *view_remap(lens, target)) if target is not None else None
    first = faces[0][1]
    return SapienCamera(spec, first.component, first.silhouette, faces=faces, cube=cube, lens=lens, view=view)


def take(sapien_scene, cam: SapienCamera) -> tuple[np.ndarray, np.ndarray]:
    """The lit picture (HxWx3 uint8) and the entity ids (HxW int32) of a pinhole camera."""
    sapien_scene.update_render()
    cam.component.take_picture()
    ids = cam.component.get_picture("Segmentation")[..., 1].astype(np.int32)
    rgba = cam.component.get_picture("Color")
    rgb = (np.clip(rgba[..., :3], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return rgb, ids


def take_ids(sapien_scene, cam: SapienCamera, sync: bool = True) -> np.ndarray:
    """The entity ids (HxW) of a pinhole camera, from its ids-only twin. `sync=False` leaves the render scene's
    poses as the last take left them (nothing moved since; a body's visibility needs no sync)."""
    if sync:
        sapien_scene.update_render()
    cam.silhouette.take_picture()
    # The ids pack (as SAPIEN's minimal one) packs position (mm) and the entity id into one int32 picture.
    return cam.silhouette.get_picture("PositionSegmentation")[..., 3].copy()


def ids_shader_dir() -> str:
    """The ids-only shader pack's folder (SAPIEN compiles a pack from a folder of GLSL files)."""
    return os.path.join(os.path.dirname(os.path.abspath(__file__)), "shaders", "ids")
