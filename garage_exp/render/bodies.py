"""Which of the loaded scene's bodies a frame draws: each body's base visibility, frustum culling, and hiding
all but a few (the silhouette renders).

Culling (`cull=True`): each frame hides the bodies whose world AABB lies wholly outside the camera's frustum
(render/cull.py), which cover no pixel, and ground truth's silhouette candidates are filtered by the same test.
Only bodies whose visibility changes are touched. With shadows on nothing is culled (a body out of view can
cast a shadow into it). docs/performance.md (issue 13) has the measured gain: frames and ground truth are
byte-identical.
"""

from __future__ import annotations

import numpy as np

from garage_exp.render.cull import frustum_planes, outside_frustum
from garage_exp.scene.description import CameraSpec


class Bodies:
    """Every body of the loaded scene, in one order: what it shows without culling (`base`), what it shows now
    (`shown`) and its world AABB (`lo`, `hi`; a moved entity's is refreshed before the next use)."""

    def __init__(self, bodies: dict[str, object] | None = None, merged: list[object] | None = None,
                 base: list[bool] | None = None, merged_boxes: np.ndarray | None = None) -> None:
        """bodies: entity name -> RenderBodyComponent of the entities with their own id; merged: the merged
        static bodies after them; base: each body's visibility without culling (None: none loaded);
        merged_boxes: the merged bodies' AABBs (n, 2, 3) when known (they never move), else read here."""
        self.all: list[object] = [*(bodies or {}).values(), *(merged or [])]
        self.index: dict[str, int] = {name: k for k, name in enumerate(bodies or {})}  # name -> position in all
        self.base = np.array(base if base is not None else [], dtype=bool)
        self.shown = np.zeros(0, dtype=bool)
        self.lo, self.hi = np.zeros((0, 3)), np.zeros((0, 3))
        self.moved: set[str] = set()
        self.culled = 0  # bodies the last in_view() hid as outside the frustum
        if self.all:
            self.shown = np.ones(len(self.all), dtype=bool)
            self.show_only(self.base)
            own = list((bodies or {}).values()) if merged_boxes is not None else self.all
            boxes = np.array([body.get_global_aabb_fast() for body in own], dtype=float).reshape(-1, 2, 3)
            if merged_boxes is not None:
                boxes = np.concatenate([boxes, np.asarray(merged_boxes, dtype=float).reshape(-1, 2, 3)])
            self.lo, self.hi = boxes[:, 0].copy(), boxes[:, 1].copy()

    def in_view(self, spec: CameraSpec, pose: np.ndarray, cull: bool) -> np.ndarray:
        """Which bodies this camera's frame draws: the base visibility, less what lies wholly outside the view
        frustum (cull.py) when `cull` is on."""
        if not cull:
            self.culled = 0
            return self.base
        self.refresh_moved()
        out = outside_frustum(frustum_planes(pose, spec), self.lo, self.hi)
        self.culled = int(np.count_nonzero(out & self.base))
        return self.base & ~out

    def only(self, names: list[str]) -> np.ndarray:
        """A mask that shows only the named entities' bodies."""
        alone = np.zeros(len(self.all), dtype=bool)
        alone[[self.index[name] for name in names]] = True
        return alone

    def refresh_moved(self) -> None:
        for name in self.moved:
            k = self.index[name]
            self.lo[k], self.hi[k] = np.asarray(self.all[k].get_global_aabb_fast(), dtype=float)
        self.moved.clear()

    def show_only(self, mask: np.ndarray) -> None:
        """Set each body's visibility to mask, touching only the bodies that change."""
        for k in np.flatnonzero(mask != self.shown):
            self.all[k].visibility = 1.0 if mask[k] else 0.0
        self.shown = mask.copy()
