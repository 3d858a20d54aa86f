"""A detector scored on a labelled image set by the project's own rules (`score_target`, as jobs score frames).

Each labelled object of a scored class (the detector's vehicle classes, its person classes) is a target: its
confidence is the models' mean confidence of the best matching detection of its kind (IoU >= detector.iou with
its box; 0 when missed), detected when that reaches detector.threshold. Per image, the false positives are the
confident detections (>= 0.25) matching no labelled object of their kind, or of a class nobody scores - as in a
job's frame table. mAP50 is COCO's AP at IoU 0.5 (pycocotools) per model, over two categories, vehicle and
person, so that a car labelled "car" and found as "truck" is found, as in jobs. Labelled objects of other
classes are not targets (counted in `ignored`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import pandas as pd

from garage_exp.perception.detect import GTBox, score_target
from garage_exp.results import cocoeval
from garage_exp.verify.data import LabelledSet

HEIGHT_BINS = (0, 16, 32, 64, 128, 256, 10**9)  # box height bands in pixels for "confidence by box height"
KIND_IDS = {"vehicle": 1, "person": 2}


@dataclass
class Scored:
    objects: pd.DataFrame  # one row per target: image, class, kind, box_height, confidence, detected, conf/<model>
    images: pd.DataFrame  # one row per image: image, targets, false_positives (mean over models), fp/<model>
    models: list[str]
    map50: dict[str, float]  # per model
    ignored: dict[str, int] = field(default_factory=dict)  # label classes that are not scored -> objects


def kind_of_class(name: str, classes: Sequence[str], person_classes: Sequence[str]) -> str | None:
    return "vehicle" if name in classes else "person" if name in person_classes else None


def score(detect, models: list[str], data: LabelledSet, classes: Sequence[str], person_classes: Sequence[str],
          iou: float, threshold: float) -> Scored:
    """`detect(rgb)` -> per-model detections (boxes, confs, classes) for one RGB frame."""
    from PIL import Image

    objects, images, ignored = [], [], {}
    gt: dict[str, list] = {"images": [], "annotations": [],
                           "categories": [{"id": i, "name": k} for k, i in KIND_IDS.items()]}
    found: dict[str, list[dict]] = {m: [] for m in models}
    for image_id, item in enumerate(data.images, start=1):
        with Image.open(item.image) as im:
            rgb = np.asarray(im.convert("RGB"))
        dets = detect(rgb)
        truth = []
        for box, name in zip(item.boxes, item.classes):
            kind = kind_of_class(name, classes, person_classes)
            if kind is None:
                ignored[name] = ignored.get(name, 0) + 1
                continue
            truth.append((name, GTBox(tuple(box), tuple(box), kind)))
        gt["images"].append({"id": image_id, "file_name": str(item.image), "width": item.width,
                             "height": item.height})
        for name, t in truth:
            s = score_target(dets, t, [g for _, g in truth], iou_threshold=iou, threshold=threshold,
                             classes=classes, person_classes=person_classes)
            x1, y1, x2, y2 = t.full_box
            objects.append({"image": item.image.name, "class": name, "kind": t.kind, "box_height": y2 - y1,
                            "confidence": s.composite, "detected": s.detected,
                            **{f"conf/{m}": c for m, c in zip(models, s.per_model)}})
            gt["annotations"].append({"id": len(gt["annotations"]) + 1, "image_id": image_id,
                                      "category_id": KIND_IDS[t.kind], "bbox": [x1, y1, x2 - x1, y2 - y1],
                                      "area": (x2 - x1) * (y2 - y1), "iscrowd": 0})
        fp = score_target(dets, None, [g for _, g in truth], iou_threshold=iou, threshold=threshold,
                          classes=classes, person_classes=person_classes)
        images.append({"image": item.image.name, "targets": len(truth),
                       "false_positives": float(np.mean(fp.false_positives_per_model)),
                       **{f"fp/{m}": n for m, n in zip(models, fp.false_positives_per_model)}})
        for m, d in zip(models, dets):
            for box, conf, cls in zip(d.boxes, d.scores, d.classes):
                kind = kind_of_class(cls, classes, person_classes)
                if kind is not None:
                    x1, y1, x2, y2 = (float(v) for v in box)
                    found[m].append({"image_id": image_id, "category_id": KIND_IDS[kind],
                                     "bbox": [x1, y1, x2 - x1, y2 - y1], "score": float(conf)})
    return Scored(pd.DataFrame(objects), pd.DataFrame(images), models,
                  {m: cocoeval.ap50(gt, found[m]) for m in models}, ignored)


def summary(scored: Scored, threshold: float) -> dict[str, float]:
    """The run's metrics: recall, map50 (mean over models), false positives per image, each per model and per
    kind, and mean confidence and recall by box height."""
    obj, img = scored.objects, scored.images
    nan = float("nan")
    out: dict[str, float] = {
        "images": float(len(img)), "targets": float(len(obj)),
        "recall": float(obj.detected.mean()) if len(obj) else nan,
        "mean_confidence": float(obj.confidence.mean()) if len(obj) else nan,
        "map50": float(np.mean(list(scored.map50.values()))),
        "fp_per_image": float(img.false_positives.mean()) if len(img) else nan}
    for m in scored.models:
        conf = obj[f"conf/{m}"] if len(obj) else pd.Series(dtype=float)
        out[f"recall/{m}"] = float((conf >= threshold).mean()) if len(obj) else nan  # the model's own recall
        out[f"mean_confidence/{m}"] = float(conf.mean()) if len(obj) else nan
        out[f"map50/{m}"] = scored.map50[m]
        out[f"fp_per_image/{m}"] = float(img[f"fp/{m}"].mean()) if len(img) else nan
    for kind in KIND_IDS:
        part = obj[obj.kind == kind] if len(obj) else obj
        if len(part):
            out[f"recall/{kind}"] = float(part.detected.mean())
            out[f"targets/{kind}"] = float(len(part))
    for lo, hi in zip(HEIGHT_BINS[:-1], HEIGHT_BINS[1:]):
        part = obj[(obj.box_height >= lo) & (obj.box_height < hi)] if len(obj) else obj
        if len(part):
            band = height_band(lo, hi)
            out[f"confidence_by_height/{band}"] = float(part.confidence.mean())
            out[f"recall_by_height/{band}"] = float(part.detected.mean())
    return out


def height_band(lo: int, hi: int) -> str:
    return f"{lo}px_up" if hi >= HEIGHT_BINS[-1] else f"{lo}-{hi}px"
