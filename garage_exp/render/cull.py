"""What a camera can provably not see, in plain numpy (no SAPIEN), so tests can check it without a device.

- `frustum_planes` / `outside_frustum`: world boxes that lie wholly on the outer side of one of the view
  frustum's six planes (near, far, four sides widened by a pixel margin) cover no pixel; the renderer hides them
  for that frame. A box that straddles a plane is kept, so nothing that shows is ever hidden.

The silhouette renders' grouping (sapien_backend.unoccluded_ids) was tried with the boxes' projected convex
hulls instead of their rectangles: on case 1 with palette=busy it made 7.92 renders a frame against 7.85 on
the research plan and 13.02 against 13.0 on garage26x30 (parked cars in view really do overlap in the image),
so the rectangles stay.
"""

from __future__ import annotations

import numpy as np

from garage_exp.scene.description import CameraSpec
from garage_exp.scene.lenses import Pinhole

MARGIN_PX = 2.0  # widening of the side planes: rasterisation may light a pixel whose centre is outside


def frustum_planes(cam_to_world: np.ndarray, spec: CameraSpec, margin_px: float = MARGIN_PX) -> np.ndarray:
    """6 x 4 world planes (nx, ny, nz, d) with inside = n.p + d >= 0 (camera axes: x forward, y left, z up)."""
    lens = Pinhole.of(spec)
    tx, ty = (lens.cx + margin_px) / lens.fx, (lens.cy + margin_px) / lens.fy
    local = np.array([[1.0, 0.0, 0.0, -spec.near], [-1.0, 0.0, 0.0, spec.far],
                      [tx, -1.0, 0.0, 0.0], [tx, 1.0, 0.0, 0.0],
                      [ty, 0.0, -1.0, 0.0], [ty, 0.0, 1.0, 0.0]])
    rot, origin = cam_to_world[:3, :3], cam_to_world[:3, 3]
    normals = local[:, :3] @ rot.T  # n_world = R n_cam
    return np.concatenate([normals, (local[:, 3] - normals @ origin)[:, None]], axis=1)


def outside_frustum(planes: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """For N world AABBs (lo, hi: N x 3), True where the box lies wholly outside one plane."""
    centre, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    # The box's largest signed distance to each plane: centre's distance plus the half-extents along |n|.
    reach = centre @ planes[:, :3].T + half @ np.abs(planes[:, :3]).T + planes[:, 3]
    return np.any(reach < 0.0, axis=1)


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])],
                    dtype=float)
