"""Parking-slot exports of the bird's-eye views: a PS2.0-like marking-point file per image, and COCO keypoints.

A job with slots (`case=slots`) writes under `slots/`:
- `images/STEM.png`: the BEV picture;
- `ps2/STEM.json`: PS2.0's label fields (Zhang et al., 2018, its .mat files) as JSON: `marks` is one
  `[x, y, direction, shape]` per marking point (BEV pixels, direction in radians atan2(d_row, d_col) along the
  separating line into the slot, shape 0 for a T, 1 for an L, as DMPR-PS's labels), `slots` one
  `[i, j, occupied]` per slot (1-based indices into `marks`, as PS2.0's; occupied 1, free 0, unknown -1), and
  beside them `corners` (each slot's 4 corners), `bays`, `meters_per_pixel` and `size`;
- `coco_keypoints.json`: one COCO keypoints annotation per slot, category "parking_slot" with keypoints
  entrance_1, entrance_2, back_2, back_1 and COCO's visibility flags: 2 seen, 1 hidden (by a car, a person or a
  pillar, or under the ego), 0 off the image. A corner's coordinates are written whatever its flag (COCO's tools
  skip the flag-0 ones), so the slot reads back whole;
- `truth/STEM.json`: the full ground truth (garage_exp/slots/truth.py: visibility per corner,
  fairness, each corner in each camera).
`read_ps2` and `read_coco_keypoints` read them back into SlotFrames.
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.slots.marks import MarkingPoint, Slot, SlotFrame

SHAPES = {"T": 0, "L": 1}
KEYPOINTS = ["entrance_1", "entrance_2", "back_2", "back_1"]
CATEGORY = {"id": 1, "name": "parking_slot", "supercategory": "parking", "keypoints": KEYPOINTS,
            "skeleton": [[1, 2], [2, 3], [3, 4], [4, 1]]}
COCO_VISIBILITY = {"visible": 2, "worn": 2, "hidden": 1, "outside": 1}


def ps2_record(frame: SlotFrame) -> dict:
    """A SlotFrame as PS2.0's label fields (plus what PS2.0 leaves implicit: corners, sizes)."""
    return {"marks": [[p.x, p.y, p.direction, SHAPES[p.shape]] for p in frame.points],
            "slots": [[s.p1 + 1, s.p2 + 1, -1 if s.occupied is None else int(bool(s.occupied))] for s in frame.slots],
            "corners": [[list(c) for c in s.corners] for s in frame.slots],
            "bays": [s.bay for s in frame.slots],
            "meters_per_pixel": frame.meters_per_pixel, "size": list(frame.size)}


def from_ps2(data: dict, where: str = "ps2") -> SlotFrame:
    try:
        shapes = {v: k for k, v in SHAPES.items()}
        points = [MarkingPoint(float(x), float(y), float(d), shapes[int(s)]) for x, y, d, s in data["marks"]]
        corners = data.get("corners") or [None] * len(data["slots"])
        bays = data.get("bays") or [""] * len(data["slots"])
        slots = []
        for (i, j, occ), quad, bay in zip(data["slots"], corners, bays):
            i, j = int(i) - 1, int(j) - 1
            if quad is None:  # PS2.0's own files: the entrance only
                quad = [(points[i].x, points[i].y), (points[j].x, points[j].y)] * 2
            slots.append(Slot(i, j, tuple((float(u), float(v)) for u, v in quad),
                              None if int(occ) < 0 else bool(occ), bay=str(bay)))
        return SlotFrame(points, slots, float(data.get("meters_per_pixel", 0.02)),
                         tuple(int(v) for v in data.get("size", (500, 500))))
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise GarageError(f"not a PS2.0-like slot label ({type(exc).__name__}: {exc})", where) from None


def read_ps2(path: Path) -> SlotFrame:
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise GarageError(f"cannot read slot labels ({exc})", str(path)) from None
    return from_ps2(data, str(path))


def read_coco_keypoints(path: Path) -> dict[str, SlotFrame]:
    """Each image's slots from a COCO keypoints file: marking points are the slots' entrance keypoints (shared
    where two slots' entrances meet)."""
    try:
        data = json.loads(Path(path).read_text())
        out = {}
        for img in data["images"]:
            out[img["id"]] = (img["file_name"], SlotFrame([], [], float(img.get("meters_per_pixel", 0.02)),
                                                          (int(img["width"]), int(img["height"]))))
        for ann in data["annotations"]:
            frame = out[ann["image_id"]][1]
            kp = np.asarray(ann["keypoints"], float).reshape(4, 3)
            attrs = ann.get("attributes", {})
            ids = []
            for k, shape in ((0, attrs.get("shapes", "TT")[0]), (1, attrs.get("shapes", "TT")[1])):
                found = next((n for n, p in enumerate(frame.points)
                              if abs(p.x - kp[k, 0]) < 1e-6 and abs(p.y - kp[k, 1]) < 1e-6), None)
                if found is None:
                    found = len(frame.points)
                    frame.points.append(MarkingPoint(float(kp[k, 0]), float(kp[k, 1]),
                                                     float(attrs.get("direction", 0.0)), shape))
                ids.append(found)
            occ = attrs.get("occupied")
            frame.slots.append(Slot(ids[0], ids[1], tuple((float(x), float(y)) for x, y, _ in kp),
                                    None if occ is None else bool(occ), bay=str(attrs.get("bay", ""))))
        return {name: frame for name, frame in out.values()}
    except (OSError, json.JSONDecodeError, KeyError, ValueError, TypeError, IndexError) as exc:
        raise GarageError(f"not a COCO keypoints file of slots ({type(exc).__name__}: {exc})", str(path)) from None


class SlotExports:
    """Writes each BEV image once, its PS2.0-like labels, its full truth, and the COCO keypoints file."""

    def __init__(self, root: Path):
        self.root = root
        for sub in ("images", "ps2", "truth"):
            (root / sub).mkdir(parents=True, exist_ok=True)
        self.images: list[dict] = []
        self.annotations: list[dict] = []

    def add(self, stem: str, bev_rgb: np.ndarray, truth) -> Path:
        """One BEV frame: `truth` is a slots.truth.SlotTruth. Returns the image's path."""
        from PIL import Image

        image = self.root / "images" / f"{stem}.png"
        Image.fromarray(bev_rgb).save(image)
        frame = truth.frame
        (self.root / "ps2" / f"{stem}.json").write_text(json.dumps(ps2_record(frame)))
        (self.root / "truth" / f"{stem}.json").write_text(json.dumps(truth.to_dict()))
        image_id = len(self.images) + 1
        h, w = bev_rgb.shape[:2]
        self.images.append({"id": image_id, "file_name": image.name, "width": w, "height": h,
                            "meters_per_pixel": frame.meters_per_pixel})
        for slot, vis, fair in zip(frame.slots, truth.visibility, truth.fair):
            kp = []
            for (x, y), v in zip(slot.corners, vis):
                flag = COCO_VISIBILITY[v] if (0 <= x < w and 0 <= y < h) else 0
                kp += [float(x), float(y), flag]
            xs, ys = [c[0] for c in slot.corners], [c[1] for c in slot.corners]
            x0, y0 = max(min(xs), 0.0), max(min(ys), 0.0)
            x1, y1 = min(max(xs), float(w)), min(max(ys), float(h))
            self.annotations.append({
                "id": len(self.annotations) + 1, "image_id": image_id, "category_id": CATEGORY["id"],
                "keypoints": kp, "num_keypoints": sum(1 for f in kp[2::3] if f > 0),
                "bbox": [x0, y0, max(x1 - x0, 0.0), max(y1 - y0, 0.0)], "area": _area(slot.corners), "iscrowd": 0,
                "attributes": {"bay": slot.bay, "occupied": slot.occupied, "fair": fair, "visibility": list(vis),
                               "shapes": frame.points[slot.p1].shape + frame.points[slot.p2].shape,
                               "direction": frame.points[slot.p1].direction}})
        return image

    def finish(self) -> Path:
        data = {"info": {"description": "garage_exp parking slots", "version": "1.0",
                         "date_created": datetime.now(timezone.utc).isoformat(timespec="seconds")},
                "licenses": [], "images": self.images, "annotations": self.annotations, "categories": [CATEGORY]}
        (self.root / "coco_keypoints.json").write_text(json.dumps(data, indent=1))
        return self.root


def _area(quad) -> float:
    x = np.array([c[0] for c in quad])
    y = np.array([c[1] for c in quad])
    return float(abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))) / 2)


SLOT_COLOURS = {True: (255, 80, 80), False: (80, 255, 80), None: (255, 255, 80)}  # occupied, free, unknown


def draw_frame(rgb: np.ndarray, frame: SlotFrame, colour=None, thickness: int = 2) -> np.ndarray:
    """A BEV picture with a SlotFrame drawn on it: each slot's quad (red occupied, green free, yellow unknown, or
    `colour`), each marking point as a dot with a tick along its direction (T filled, L hollow)."""
    import cv2

    out = np.ascontiguousarray(rgb.copy())
    for slot in frame.slots:
        quad = np.round(np.array(slot.corners)).astype(np.int32)
        cv2.polylines(out, [quad], True, colour or SLOT_COLOURS[slot.occupied], thickness, cv2.LINE_AA)
    for p in frame.points:
        c = (int(round(p.x)), int(round(p.y)))
        tip = (int(round(p.x + 15 * np.cos(p.direction))), int(round(p.y + 15 * np.sin(p.direction))))
        cv2.line(out, c, tip, colour or (255, 255, 255), thickness, cv2.LINE_AA)
        cv2.circle(out, c, 4, colour or (255, 255, 255), -1 if p.shape == "T" else thickness, cv2.LINE_AA)
    return out


def draw(root: Path, image: str | None = None) -> tuple[np.ndarray, str]:
    """One exported BEV image with its slots as the COCO keypoints file has them (`python -m garage_exp.exports
    SLOTS_DIR`)."""
    from PIL import Image

    frames = read_coco_keypoints(root / "coco_keypoints.json")
    if not frames:
        raise GarageError("no images in the slot export", str(root / "coco_keypoints.json"))
    name = image or next(iter(frames))
    if name not in frames:
        raise GarageError(f"no image {name!r} in the slot export (have {', '.join(list(frames)[:5])}...)",
                          str(root / "coco_keypoints.json"))
    rgb = np.asarray(Image.open(root / "images" / name).convert("RGB"))
    return draw_frame(rgb, frames[name]), name
