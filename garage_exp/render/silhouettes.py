"""Which vehicles' unoccluded silhouettes can share one render, in plain numpy (no SAPIEN).

A renderer draws each vehicle's silhouette alone (everything else hidden) with an ids-only camera. Vehicles
whose world bounding boxes project to disjoint image rectangles cannot hide one another, so they share one
render; only overlapping ones cost an extra render each. Grouping by the boxes' projected convex hulls instead
of rectangles was tried and measured no better (render/cull.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from garage_exp.render.cull import box_corners
from garage_exp.scene.camera import to_camera
from garage_exp.scene.description import CameraSpec
from garage_exp.scene.lenses import Pinhole


def image_rect(aabb: np.ndarray, cam_to_world: np.ndarray, spec: CameraSpec) -> tuple[float, ...] | None:
    """The image rectangle (x1, y1, x2, y2) that a world AABB can cover, or None when it misses the image."""
    lo, hi = np.asarray(aabb, dtype=float)
    local = to_camera(cam_to_world, box_corners(lo, hi))
    if np.all(local[:, 0] <= spec.near):
        return None
    if np.any(local[:, 0] <= spec.near):
        return 0.0, 0.0, float(spec.width), float(spec.height)  # straddles the camera: assume anywhere
    u, v = Pinhole.of(spec).pixels(local)
    x1, x2 = max(u.min(), 0.0), min(u.max(), spec.width)
    y1, y2 = max(v.min(), 0.0), min(v.max(), spec.height)
    if x1 >= x2 or y1 >= y2:
        return None
    return x1 - 1.0, y1 - 1.0, x2 + 1.0, y2 + 1.0  # a pixel of margin for rasterisation


def disjoint_groups(rects: dict[str, tuple[float, ...]]) -> list[list[str]]:
    """Greedy grouping of names whose rectangles do not overlap any other in the same group."""
    groups: list[list[str]] = []
    for name, r in rects.items():
        for group in groups:
            if all(not overlap(r, rects[other]) for other in group):
                group.append(name)
                break
        else:
            groups.append([name])
    return groups


def overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]
