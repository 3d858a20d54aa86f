"""One exported frame drawn from its files alone, as a user's tools read them: COCO boxes (pycocotools) and
KITTI 3D boxes projected with the frame's calib P2. A check that the exports sit on the actors."""

from __future__ import annotations

import contextlib
import csv
import io
from pathlib import Path

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.exports import kitti
from garage_exp.exports.kitti import Box3D

# Edges of KITTI's devkit corner order (bottom face 0-3, top face 4-7): the front face (0, 1, 5, 4) is drawn
# crossed, so the heading shows.
BOX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7),
             (0, 5), (1, 4)]


def read_label(path: Path) -> list[tuple[str, tuple[float, float, float, float], Box3D | None]]:
    """(type, 2D box, 3D box or None when KITTI's unknown values) per line of a label_2 file."""
    out = []
    for k, line in enumerate(path.read_text().splitlines(), 1):
        fields = line.split()
        try:
            values = [float(v) for v in fields[1:]]
        except ValueError:
            values = []
        if len(fields) != 15 or not values:
            raise GarageError("not a KITTI label line (15 fields: type and 14 numbers)", f"{path}:{k}")
        box = None if values[7] < 0 else Box3D(tuple(values[7:10]), tuple(values[10:13]), values[13])
        out.append((fields[0], tuple(values[3:7]), box))
    return out


def read_p2(path: Path) -> np.ndarray:
    for line in path.read_text().splitlines():
        if line.startswith("P2:"):
            values = line.split()[1:]
            if len(values) == 12:
                return np.array([float(v) for v in values]).reshape(3, 4)
    raise GarageError("no P2 line of 12 numbers", str(path))


def draw(root: Path, image_name: str | None = None) -> tuple[np.ndarray, str]:
    """The image (first of coco.json when None) with each COCO annotation's box (green; its visible part
    yellow) and each KITTI object's 3D box (red; the front face crossed); (picture, image name)."""
    import cv2
    from pycocotools.coco import COCO

    coco_path = root / "coco.json"
    if not coco_path.is_file():
        raise GarageError("no coco.json: not a dataset written with dataset=true", str(root))
    with contextlib.redirect_stdout(io.StringIO()):  # pycocotools reports its loading on stdout
        gt = COCO(str(coco_path))
    images = {img["file_name"]: img for img in gt.dataset["images"]}
    name = image_name or next(iter(images), None)
    if name not in images:
        raise GarageError(f"no image {name!r} in it", str(coco_path))
    picture = cv2.imread(str(root / "images" / name))
    if picture is None:
        raise GarageError("missing or unreadable", str(root / "images" / name))
    rgb = cv2.cvtColor(picture, cv2.COLOR_BGR2RGB)
    for ann in gt.loadAnns(gt.getAnnIds(imgIds=[images[name]["id"]])):
        x, y, w, h = map(int, ann["bbox"])
        cv2.rectangle(rgb, (x, y), (x + w - 1, y + h - 1), (0, 220, 0), 2)
        vx, vy, vw, vh = map(int, ann["attributes"]["visible_bbox"])
        cv2.rectangle(rgb, (vx, vy), (vx + vw - 1, vy + vh - 1), (240, 220, 0), 1)
        text = f"{gt.loadCats(ann['category_id'])[0]['name']} vis {ann['attributes']['visible_fraction']:.2f}"
        cv2.putText(rgb, text, (x + 2, max(10, y - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 0), 1, cv2.LINE_AA)
    frames = root / "kitti" / "frames.csv"
    with open(_existing(frames)) as fh:
        ids = {row.get("image"): row.get("kitti_id") for row in csv.DictReader(fh)}
    if Path(name).stem not in ids:
        raise GarageError(f"no KITTI frame for {name!r}", str(frames))
    frame_id = ids[Path(name).stem]
    p2 = read_p2(_existing(root / "kitti" / "calib" / f"{frame_id}.txt"))
    size = (rgb.shape[1], rgb.shape[0])
    for _, _, box in read_label(_existing(root / "kitti" / "label_2" / f"{frame_id}.txt")):
        if box is None:
            continue
        corners = kitti.corners(box)
        for a, b in BOX_EDGES:
            segment = _in_front(corners[a], corners[b])
            if segment is None:
                continue
            (u1, v1), (u2, v2) = kitti.project(p2, np.array(segment))
            ok, p, q = cv2.clipLine((0, 0, *size), (int(round(u1)), int(round(v1))), (int(round(u2)), int(round(v2))))
            if ok:
                cv2.line(rgb, p, q, (230, 30, 30), 1, cv2.LINE_AA)
    return rgb, name


def _in_front(a: np.ndarray, b: np.ndarray, near: float = 0.1):
    """The part of the edge a-b in front of the camera (z >= near, KITTI's frame), or None."""
    if a[2] < near and b[2] < near:
        return None
    if a[2] < near or b[2] < near:
        t = (near - a[2]) / (b[2] - a[2])
        cut = a + t * (b - a)
        return (cut, b) if a[2] < near else (a, cut)
    return a, b


def _existing(path: Path) -> Path:
    if not path.is_file():
        raise GarageError("missing", str(path))
    return path
