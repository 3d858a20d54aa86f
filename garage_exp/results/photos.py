"""The two photos ultralytics ships (bus.jpg: a bus and four people; zidane.jpg: two people and two ties), labelled
by hand, as a labelled real-photo set for `python -m garage_exp.verify`: the tests' check of the command and the
loop's real-photo suite (a detector that forgets the real world while fine-tuned on renders shows it here). And a
second, larger set the loop scores beside it: 11 street photos from Debian's OpenCV samples (assets/photos.py),
13 cars and 19 people, so that one missed object moves recall by 0.03 rather than 0.14.

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

# The street set (assets/photos.py fetches the photos from Debian's opencv-doc and node-opencv): 13 cars and 19
# people in 11 photos, labelled by hand over a 50 px grid and zoomed crops, no detector involved (its proposals
# would bias the check toward it). Each entry: (width, height, labelled, ignored); the ignored objects (under
# ~20 px or a sliver at an edge) are COCO crowd regions: not required for recall (verify leaves crowd regions out,
# so a detection of one counts as a false positive, as on any unlabelled object). Vans and SUVs are cars.
STREET_LABELS = {
    # a street behind a "no double parking" sign: a silver wagon (its front behind the pole), a white sedan mostly
    # hidden by newspaper boxes and a man, the man (cut by the left and bottom edges), a woman cut by the right edge
    "scenetext01.jpg": (800, 600, [("car", (399, 419, 697, 574)), ("car", (66, 423, 226, 500)),
                                   ("pedestrian", (0, 318, 105, 600)), ("pedestrian", (673, 364, 797, 600))], []),
    # no-parking barriers on a road: a white vehicle's underside and wheels cut by the top edge (the hard one); a
    # dark car's corner behind the barrier at the left edge (ignored)
    "scenetext05.jpg": (1280, 960, [("car", (122, 0, 288, 62))], [("car", (0, 128, 55, 256))]),
    # a shop front: a red hatchback cut by the bottom edge behind a lamp post; a head at the bottom edge (ignored)
    "scenetext06.jpg": (640, 480, [("car", (85, 391, 220, 480))], [("pedestrian", (550, 444, 582, 480))]),
    # a silver sedan's rear filling the frame, heavily motion-blurred
    "licenseplate_motion.jpg": (600, 482, [("car", (0, 30, 600, 408))], []),
    # two men playing basketball indoors, near greyscale; the right one cut by the right and bottom edges
    "basketball1.png": (640, 480, [("pedestrian", (37, 84, 161, 478)), ("pedestrian", (436, 22, 640, 480))], []),
    "basketball2.png": (640, 480, [("pedestrian", (37, 84, 162, 478)), ("pedestrian", (428, 19, 640, 480))], []),
    # two sedans from the side, whole in the frame
    "car1.jpg": (1024, 680, [("car", (52, 198, 955, 478))], []),
    "car2.jpg": (1500, 938, [("car", (145, 336, 1385, 725))], []),
    # a campus from above (frames 0, 400, 790 of vtest.avi): walking people 60-110 px tall, a white van and a car
    # cut by the right edge, both small and far; in frame 790 people overlap and one leans into the car's boot
    # (legs only: ignored)
    "vtest_000.png": (768, 576, [("pedestrian", (254, 220, 282, 308)), ("pedestrian", (500, 157, 530, 233)),
                                 ("pedestrian", (639, 240, 684, 320)), ("car", (651, 44, 723, 98)),
                                 ("car", (735, 49, 768, 94))], []),
    "vtest_400.png": (768, 576, [("pedestrian", (273, 200, 302, 285)), ("pedestrian", (590, 141, 617, 204)),
                                 ("pedestrian", (688, 300, 743, 410)), ("car", (651, 44, 723, 98)),
                                 ("car", (735, 49, 768, 94))], []),
    "vtest_790.png": (768, 576, [("pedestrian", (224, 160, 249, 231)), ("pedestrian", (244, 193, 274, 268)),
                                 ("pedestrian", (367, 168, 403, 235)), ("pedestrian", (421, 271, 451, 377)),
                                 ("pedestrian", (653, 145, 674, 213)), ("pedestrian", (634, 222, 669, 324)),
                                 ("pedestrian", (601, 263, 641, 370)), ("car", (651, 44, 723, 98)),
                                 ("car", (733, 48, 768, 94))], [("pedestrian", (754, 58, 768, 96))]),
}
STREET_CLASSES = ["car", "pedestrian"]


def write_photos(root: Path) -> Path:
    """images/ with the two photos ultralytics ships, coco.json, and YOLO labels/ and data.yaml over the same
    images."""
    import ultralytics

    assets = Path(ultralytics.__file__).parent / "assets"
    return write_set(root, {name: (w, h, objects, []) for name, (w, h, objects) in LABELS.items()}, assets, CLASSES)


def write_street_photos(root: Path) -> Path:
    """The same for the street set (its photos fetched at set-up: assets/photos.py)."""
    from garage_exp.assets.photos import street_photos

    return write_set(root, STREET_LABELS, street_photos(), STREET_CLASSES)


def write_set(root: Path, labels: dict, source: Path, classes: list[str]) -> Path:
    """Copies of the labelled photos under root/images, their coco.json (ignored objects as crowd regions), and
    YOLO labels/ (the labelled objects alone) with a data.yaml."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "labels").mkdir(exist_ok=True)
    coco = {"images": [], "annotations": [], "categories": [{"id": k + 1, "name": n} for k, n in enumerate(classes)]}
    for image_id, (name, (w, h, objects, ignored)) in enumerate(labels.items(), start=1):
        shutil.copyfile(source / name, root / "images" / name)
        coco["images"].append({"id": image_id, "file_name": name, "width": w, "height": h})
        rows = []
        for crowd, group in ((0, objects), (1, ignored)):
            for cls, (x1, y1, x2, y2) in group:
                coco["annotations"].append({"id": len(coco["annotations"]) + 1, "image_id": image_id,
                                            "iscrowd": crowd, "category_id": classes.index(cls) + 1,
                                            "bbox": [x1, y1, x2 - x1, y2 - y1], "area": (x2 - x1) * (y2 - y1)})
                if not crowd:
                    rows.append(f"{classes.index(cls)} {(x1 + x2) / 2 / w:.6f} {(y1 + y2) / 2 / h:.6f} "
                                f"{(x2 - x1) / w:.6f} {(y2 - y1) / h:.6f}")
        (root / "labels" / name).with_suffix(".txt").write_text("\n".join(rows) + "\n")
    (root / "coco.json").write_text(json.dumps(coco))
    (root / "data.yaml").write_text(yaml.safe_dump({"path": str(root), "val": "images", "names": classes}))
    return root
