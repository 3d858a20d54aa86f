"""Dataset labels: COCO's class names and ids for the actors, which actors a dataset labels, and the YOLO-format
frame writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np

COCO_IDS = {"person": 0, "car": 2, "bus": 5, "truck": 7}
PERSON_CLASSES = ("person",)
KIND_TO_COCO = {"car": "car", "suv": "car", "pickup": "truck", "van": "truck", "bus": "bus", "truck": "truck"}


class DatasetWriter:
    """Frames with YOLO-format labels from ground truth (class x_centre y_centre w h, normalised; COCO ids:
    person 0, car 2, bus 5, truck 7), so a detector can be fine-tuned on the hard cases."""

    def __init__(self, root: Path):
        self.root = root
        (root / "images").mkdir(parents=True, exist_ok=True)
        (root / "labels").mkdir(parents=True, exist_ok=True)

    def add(self, stem: str, rgb: np.ndarray, truth, scene) -> None:
        from PIL import Image

        h, w = rgb.shape[:2]
        Image.fromarray(rgb).save(self.root / "images" / f"{stem}.png")
        lines = []
        for t in labelled(truth):
            x1, y1, x2, y2 = t.full_box
            lines.append(f"{COCO_IDS[coco_class(scene, t)]} {(x1 + x2) / 2 / w:.6f} {(y1 + y2) / 2 / h:.6f} "
                         f"{(x2 - x1) / w:.6f} {(y2 - y1) / h:.6f}")
        (self.root / "labels" / f"{stem}.txt").write_text("\n".join(lines) + ("\n" if lines else ""))

    def finish(self) -> Path:
        import yaml

        # All 80 COCO names with COCO's ids, so a COCO-pretrained detector fine-tunes on it without remapping.
        data = {"path": str(self.root), "train": "images", "val": "images", "names": coco_names()}
        (self.root / "data.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
        return self.root


def coco_names() -> dict[int, str]:
    """COCO's 80 class names by id, from ultralytics' own dataset config (no download)."""
    from importlib.resources import files

    import yaml

    text = (files("ultralytics") / "cfg" / "datasets" / "coco.yaml").read_text()
    return {int(k): str(v) for k, v in yaml.safe_load(text)["names"].items()}


def labelled(truth) -> list:
    """The actors a dataset labels (in every format): those with at least one visible pixel."""
    return [t for t in truth if t.visible_box and t.visible_pixels > 0]


def coco_class(scene, t) -> str:
    """The COCO class name of a ground-truth record: person, or its vehicle kind's (car, bus, truck)."""
    if getattr(t, "kind", "vehicle") == "person":
        return "person"
    return KIND_TO_COCO.get(vehicle_kind(scene, t.name), "car")


def vehicle_kind(scene, name: str) -> str:
    """car, suv, pickup, van, bus or truck, from the entity's model name ('car' when the scene lacks it)."""
    try:
        entity = scene.entity(name)
    except KeyError:
        return "car"
    from garage_exp.scene.kinds import kind_of

    return kind_of(entity.model or "")
