"""Pixel work on rendered frames that every backend shares: the blank control's composite, and the contact
shadow it keeps under the car."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

from garage_exp.core import arrays
from garage_exp.render.base import BLANK_GREY, Frame
from garage_exp.scene.description import Decal, Pose


def blank_composite(rgb, frame: Frame, ids: Mapping[str, int], names: Iterable[str], shadow=None):
    """The named entities' pixels of `rgb` (a picture of `frame`) pasted on uniform BLANK_GREY; `ids` is the
    renderer's entity name -> id map (`Renderer.ids`). shadow: an HxW alpha (numpy, `floor_alpha`) that darkens
    the grey as a black decal of that alpha would (in linear light), or None: the grey is uniform.

    The blank control proper is a scene with `background=False`, which renders every vehicle whole on grey with
    the same lights. Compositing on top of that drops the other vehicles; on a full render it keeps the target
    as the occluders cut it (a different control: occlusion without background).
    """
    keep = arrays.isin(frame.ids, [ids[n] for n in names if n in ids])  # numpy or torch, as the frame
    out = arrays.xp(rgb).full_like(rgb, BLANK_GREY)
    if shadow is not None:
        out[...] = arrays.table(shaded_grey(shadow), rgb)[..., None]
    out[keep] = rgb[keep]
    return out


def shaded_grey(alpha: np.ndarray) -> np.ndarray:
    """BLANK_GREY under a black decal of `alpha` (HxW in [0, 1]), blended in linear light: HxW uint8 sRGB."""
    from garage_exp.scene.textures import srgb8

    linear = ((BLANK_GREY / 255.0 + 0.055) / 1.055) ** 2.4  # 128 lies above sRGB's linear toe
    shade = (linear * (1.0 - np.clip(alpha, 0.0, 1.0))).astype(np.float32)
    return np.ascontiguousarray(srgb8(np.repeat(shade[..., None], 4, axis=2))[..., 0])


def floor_alpha(frame: Frame, pose: Pose, decal: Decal) -> np.ndarray | None:
    """The alpha of `decal` (a flat picture on the floor, carried by an entity at `pose`) as `frame` sees it:
    its picture warped onto the image by the floor-to-image homography (HxW float32, 0 off the decal). None when
    the frame has a lens model (fisheye) or a corner lies behind the camera: no shadow is drawn then."""
    import cv2

    from garage_exp.scene.textures import image

    if not frame.lens.perspective:
        return None
    at = pose.compose(decal.offset)
    c, s = math.cos(math.radians(at.yaw)), math.sin(math.radians(at.yaw))
    hx, hy = decal.size[0] / 2.0, decal.size[1] / 2.0
    # the picture's columns run along the decal's x, its rows along its y (scene/textures.py)
    corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
    world = np.array([[at.x + c * x - s * y, at.y + s * x + c * y, at.z] for x, y in corners])
    pixels, depth = frame.project(world)
    if np.any(depth <= 1e-3):
        return None
    alpha = np.ascontiguousarray(image(decal.material)[0][..., 3])
    h, w = alpha.shape
    src = np.float32([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    homography = cv2.getPerspectiveTransform(src, (pixels - 0.5).astype(np.float32))  # cv2: pixel centres
    return cv2.warpPerspective(alpha, homography, (frame.width, frame.height), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)


def contact_shadow(frame: Frame, entity, pose: Pose) -> np.ndarray | None:
    """The alpha of `entity`'s contact shadow (its decal, when the look gives it one) at `pose` in `frame`."""
    decal = next((shape for shape in entity.shapes if isinstance(shape, Decal)), None)
    return None if decal is None else floor_alpha(frame, pose, decal)
