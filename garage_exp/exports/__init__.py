"""The dataset a job writes with dataset=true, in the formats users' tools read: YOLO (labels.DatasetWriter),
COCO (dataset/coco.json) and KITTI (dataset/kitti/), the same actors in each, from the same ground truth.

The job hands each frame's camera and actor poses over as plain data (`FrameGeometry`); KITTI's 3D boxes come
from them and the scene description's extents.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from garage_exp.results import labels
from garage_exp.exports import coco, kitti
from garage_exp.scene.description import Pose, Scene


@dataclass(frozen=True)
class FrameGeometry:
    """Where the camera was and what it was (render.Frame without its pictures), and where each actor stood."""

    cam_to_world: np.ndarray  # 4x4, the camera's axes x forward, y left, z up (garage_exp.scene.camera)
    K: np.ndarray  # the 3x3 camera matrix (a pinhole frame's: scene/lenses)
    width: int
    height: int
    poses: Mapping[str, Pose] = field(default_factory=dict)

    @classmethod
    def of(cls, frame) -> FrameGeometry:
        return cls(frame.cam_to_world.copy(), frame.lens.K, frame.width, frame.height, dict(frame.poses))


class DatasetExports:
    """Writes every frame once as an image and labels it in the three formats."""

    def __init__(self, root: Path):
        self.root = root
        self.yolo = labels.DatasetWriter(root)
        self.coco = coco.CocoWriter(root / "coco.json")
        self.kitti = kitti.KittiWriter(root / "kitti")

    def add(self, stem: str, camera: str, rgb: np.ndarray, truth, scene: Scene, geometry: FrameGeometry) -> None:
        self.yolo.add(stem, rgb, truth, scene)
        image = self.root / "images" / f"{stem}.png"
        objects, lines = [], []
        for t in labels.labelled(truth):
            kind = "person" if t.kind == "person" else labels.vehicle_kind(scene, t.name)
            objects.append((labels.coco_class(scene, t), kind, t))
            entity = scene.entity(t.name)  # ground truth exists only for the scene's actors
            box = kitti.box3d(entity, geometry.poses.get(t.name, entity.pose), geometry.cam_to_world)
            lines.append(kitti.label_line(kind, t, box))
        h, w = rgb.shape[:2]
        self.coco.add(image.name, w, h, camera, objects)
        self.kitti.add(image, kitti.projection(geometry.cam_to_world, geometry.K), lines)

    def finish(self) -> Path:
        self.coco.finish()
        self.kitti.finish()
        return self.yolo.finish()
