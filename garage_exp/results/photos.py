"""The two photos ultralytics ships (bus.jpg: a bus and four people; zidane.jpg: two people and two ties), labelled
by hand, as a labelled real-photo set for `python -m garage_exp.verify`: the tests' check of the command and the
loop's real-photo suite (a detector that forgets the real world while fine-tuned on renders shows it here).

    python -m garage_exp.verify data=DIR/coco.json +label_map.pedestrian=person ...
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import yaml

# Hand-made labels (x1, y1, x2, y2 pixels), drawn on the photos over a 50 px grid. The fourth person of bus.jpg
# is cut by the left edge (only an arm, a leg and a shoulder show): the hard one. "pedestrian" is mapped to the
# project's "person" by label_map; ties are labelled but not scored.
LABELS = {
    "bus.jpg": (810, 1080, [("bus", (12, 232, 803, 735)), ("pedestrian", (52, 398, 245, 905)),
                            ("pedestrian", (222, 405, 345, 860)), ("pedestrian", (668, 395, 810, 880)),
                            ("pedestrian", (0, 545, 78, 875))]),
    "zidane.jpg": (1280, 720, [("pedestrian", (150, 200, 1150, 720)), ("pedestrian", (750, 42, 1140, 720)),
                               ("tie", (440, 410, 500, 720)), ("tie", (990, 300, 1030, 470))]),
}
CLASSES = ["bus", "pedestrian", "tie"]
LABEL_MAP = ["+label_map.pedestrian=person"]  # the verify overrides that score its people as persons


def write_photos(root: Path) -> Path:
    """images/ with the two photos, coco.json, and YOLO labels/ and data.yaml over the same images."""
    import ultralytics

    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "labels").mkdir(exist_ok=True)
    coco = {"images": [], "annotations": [], "categories": [{"id": k + 1, "name": n} for k, n in enumerate(CLASSES)]}
    for image_id, (name, (w, h, objects)) in enumerate(LABELS.items(), start=1):
        shutil.copyfile(Path(ultralytics.__file__).parent / "assets" / name, root / "images" / name)
        coco["images"].append({"id": image_id, "file_name": name, "width": w, "height": h})
        rows = []
        for cls, (x1, y1, x2, y2) in objects:
            coco["annotations"].append({"id": len(coco["annotations"]) + 1, "image_id": image_id, "iscrowd": 0,
                                        "category_id": CLASSES.index(cls) + 1, "bbox": [x1, y1, x2 - x1, y2 - y1],
                                        "area": (x2 - x1) * (y2 - y1)})
            rows.append(f"{CLASSES.index(cls)} {(x1 + x2) / 2 / w:.6f} {(y1 + y2) / 2 / h:.6f} {(x2 - x1) / w:.6f} "
                        f"{(y2 - y1) / h:.6f}")
        (root / "labels" / name).with_suffix(".txt").write_text("\n".join(rows) + "\n")
    (root / "coco.json").write_text(json.dumps(coco))
    (root / "data.yaml").write_text(yaml.safe_dump({"path": str(root), "val": "images", "names": CLASSES}))
    return root
