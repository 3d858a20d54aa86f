"""A COCO-format annotation file (instances, bbox) from the scene's ground truth.

Category ids are COCO's own (person 1, car 3, bus 6, truck 8, as in instances_*.json), not the 0-79 indices of
the YOLO labels, so COCO tools and COCO-pretrained detectors' results match them. `bbox` is the actor's full
(amodal) box within the image, as in the YOLO labels; `area` is its visible pixel count (the area of what can be
seen, COCO's mask area). Each annotation's `attributes` say how visible it is.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

from garage_exp.perception.groundtruth import OCCLUSION_NAMES, VehicleTruth

CATEGORIES = [{"id": 1, "name": "person", "supercategory": "person"},
              {"id": 3, "name": "car", "supercategory": "vehicle"},
              {"id": 6, "name": "bus", "supercategory": "vehicle"},
              {"id": 8, "name": "truck", "supercategory": "vehicle"}]
CATEGORY_IDS = {c["name"]: c["id"] for c in CATEGORIES}
# CityPersons' visibility bins (Zhang et al., 2017): bare >= 0.9, partial >= 0.65, heavy >= 0.2 (its "heavy
# occlusion" subset); below 0.2 its evaluations leave the box out.
CITYPERSONS_BINS = ((0.9, "bare"), (0.65, "partial"), (0.2, "heavy"), (0.0, "beyond_heavy"))


def citypersons_bin(visible_fraction: float) -> str:
    return next(name for low, name in CITYPERSONS_BINS if visible_fraction >= low)


def xywh(box: tuple[int, int, int, int]) -> list[float]:
    x1, y1, x2, y2 = box
    return [float(x1), float(y1), float(x2 - x1), float(y2 - y1)]


class CocoWriter:
    """Collects images and annotations; `finish` writes the file."""

    def __init__(self, path: Path):
        self.path = path
        self.images: list[dict] = []
        self.annotations: list[dict] = []

    def add(self, file_name: str, width: int, height: int, camera: str, objects: list[tuple[str, str, VehicleTruth]]
            ) -> None:
        """objects: (COCO class name, vehicle kind, truth) of each labelled actor in the image."""
        image_id = len(self.images) + 1
        self.images.append({"id": image_id, "file_name": file_name, "width": width, "height": height,
                            "camera": camera})
        for coco_class, kind, t in objects:
            self.annotations.append({
                "id": len(self.annotations) + 1, "image_id": image_id, "category_id": CATEGORY_IDS[coco_class],
                "bbox": xywh(t.full_box), "area": float(t.visible_pixels), "iscrowd": 0,
                "attributes": {
                    "name": t.name, "role": t.role, "kind": kind,
                    "visible_fraction": round(t.visible_fraction, 6), "visible_bbox": xywh(t.visible_box),
                    "occlusion": t.occlusion, "occlusion_name": OCCLUSION_NAMES[t.occlusion],
                    "citypersons_occlusion": citypersons_bin(t.visible_fraction),
                    "truncation": round(t.truncation, 4), "kitti_difficulty": t.kitti,
                    "distance": round(t.distance, 4)}})

    def finish(self) -> Path:
        data = {"info": {"description": "garage_exp ground truth", "version": "1.0",
                         "date_created": datetime.now(timezone.utc).isoformat(timespec="seconds")},
                "licenses": [], "images": self.images, "annotations": self.annotations, "categories": CATEGORIES}
        self.path.write_text(json.dumps(data, indent=1))
        return self.path
