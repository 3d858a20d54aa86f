"""Score one target (a vehicle or a person) from several models' detections (the research's composite
confidence).

Detection classes follow the actor: a vehicle target is matched by the vehicle classes (car, truck, bus), a
person by the person classes. Ground truth says which it is by its `kind` ("vehicle" when it has none)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from garage_exp.core.errors import GarageError, check_range

Box = tuple[float, float, float, float]  # x1, y1, x2, y2 in pixels
VEHICLE_CLASSES = ("car", "truck", "bus")
PERSON_CLASSES = ("person",)
MATCH_MODES = ("full", "visible", "either")


@dataclass(frozen=True)
class GTBox:
    """A ground-truth vehicle for callers without `groundtruth` records: the full box (unoccluded silhouette)
    and the box of its visible part (None when nothing of it is visible)."""

    full_box: Box | None
    visible_box: Box | None = None
    kind: str = "vehicle"  # "vehicle" | "person"


@dataclass(frozen=True)
class Scoring:
    """The job's matching rule (the `detector` group's iou, match and threshold, in the job spec): how a
    detection counts as the target's, and the composite confidence that counts as detected."""

    threshold: float = 0.5
    iou: float = 0.5
    match: str = "full"

    @classmethod
    def of(cls, node) -> "Scoring":
        return cls(float(node.threshold), float(node.iou), str(node.match))

    def score(self, dets: Sequence[Any], target: Any, truth: Sequence[Any] = (), **classes) -> "TargetScore":
        """`score_target` under this rule; classes: the detector's (`Detector.scoring()`)."""
        return score_target(dets, target, truth, iou_threshold=self.iou, match=self.match,
                            threshold=self.threshold, **classes)


@dataclass
class TargetScore:
    per_model: list[float]  # best matching confidence (of the target's classes) per model, 0 when missed
    composite: float  # mean of per_model
    detected: bool  # composite >= threshold
    false_positives: int  # summed over models
    false_positives_per_model: list[int]
    matched: list[int]  # index of the matching detection per model, -1 when missed


def iou(a: Sequence[float], b: Sequence[float]) -> float:
    """Intersection over union of two xyxy boxes; 0 for empty boxes."""
    return float(iou_many(np.asarray([a], dtype=float), b)[0])


def iou_many(boxes: np.ndarray, box: Sequence[float] | None) -> np.ndarray:
    """IoU of each of N xyxy boxes against one box (zeros when the box is None)."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    if box is None:
        return np.zeros(len(boxes))
    x1, y1, x2, y2 = (float(v) for v in box)
    iw = np.clip(np.minimum(boxes[:, 2], x2) - np.maximum(boxes[:, 0], x1), 0.0, None)
    ih = np.clip(np.minimum(boxes[:, 3], y2) - np.maximum(boxes[:, 1], y1), 0.0, None)
    inter = iw * ih
    area_a = np.clip(boxes[:, 2] - boxes[:, 0], 0, None) * np.clip(boxes[:, 3] - boxes[:, 1], 0, None)
    area_b = max(x2 - x1, 0.0) * max(y2 - y1, 0.0)
    union = area_a + area_b - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def target_iou(boxes: np.ndarray, truth: Any, match: str) -> np.ndarray:
    """IoU of detections against a ground-truth vehicle by match mode; "either" takes the better of the two."""
    full, visible = _boxes_of(truth)
    if match == "full":
        return iou_many(boxes, full)
    if match == "visible":
        return iou_many(boxes, visible)
    return np.maximum(iou_many(boxes, full), iou_many(boxes, visible))


def check_match(match: str, iou_threshold: float, threshold: float) -> None:
    """The `detector` group's matching values (detector.check_detector checks the rest)."""
    if match not in MATCH_MODES:
        raise GarageError(f"unknown match {match!r} ({' | '.join(MATCH_MODES)})", "detector.match")
    if not 0.0 < float(iou_threshold) <= 1.0:
        raise GarageError(f"iou {iou_threshold} is outside (0, 1]", "detector.iou")
    check_range(threshold, 0.0, 1.0, "detector.threshold")


def score_target(dets: Sequence[Any], target: Any, truth: Sequence[Any] = (), iou_threshold: float = 0.5,
                 match: str = "full", threshold: float = 0.5, classes: Sequence[str] = VEHICLE_CLASSES,
                 fp_conf: float = 0.25, person_classes: Sequence[str] = PERSON_CLASSES) -> TargetScore:
    """Score the target in one frame.

    dets: per-model detections (`Detections`: boxes, scores, classes). target: the target's ground truth,
    any object with `full_box` and `visible_box` (a `groundtruth` record or `GTBox`), a bare xyxy box (used as
    both), or None when the target is out of view (scores 0). truth: every ground-truth actor in the frame
    (the target may be among them), for false positives. match: which target box a detection must overlap
    with IoU >= iou_threshold: "full" | "visible" | "either". threshold: composite confidence counted as
    detected. classes: the vehicle classes; person_classes: the person classes. A target or truth record
    whose `kind` is "person" is matched by the person classes, any other by the vehicle classes.
    fp_conf: detections below this confidence are not counted as false positives: the detector keeps hits
    down to ~0.05 so that weak target hits still score, but nobody would act on a 0.05 box.
    A false positive is a vehicle (person) detection overlapping no ground-truth vehicle's (person's) full or
    visible box (either box whatever the match mode, so that occlusion does not manufacture false positives),
    or any detection of another class.
    """
    check_match(match, iou_threshold, threshold)
    groups = {"vehicle": set(classes), "person": set(person_classes)}
    others = list(truth)
    if target is not None and not any(t is target for t in others):
        others.append(target)
    per_model, matched, fps = [], [], []
    for model in dets:
        boxes = np.asarray(model.boxes, dtype=float).reshape(-1, 4)
        confs = np.asarray(model.scores, dtype=float).reshape(-1)
        of = {kind: np.array([c in names for c in model.classes], dtype=bool) for kind, names in groups.items()}
        best, best_index = 0.0, -1
        if target is not None and len(boxes):
            hits = of[kind_of(target)] & (target_iou(boxes, target, match) >= iou_threshold)
            if hits.any():
                best_index = int(np.flatnonzero(hits)[np.argmax(confs[hits])])
                best = float(confs[best_index])
        per_model.append(best)
        matched.append(best_index)
        fps.append(_false_positives(boxes, confs, of, others, iou_threshold, fp_conf))
    composite = float(np.mean(per_model)) if per_model else 0.0
    return TargetScore(per_model=per_model, composite=composite, detected=composite >= threshold,
                       false_positives=int(sum(fps)), false_positives_per_model=fps, matched=matched)


def kind_of(truth: Any) -> str:
    """"person" or "vehicle" for a ground-truth record, a `GTBox` or a bare box (a vehicle)."""
    return "person" if getattr(truth, "kind", "vehicle") == "person" else "vehicle"


def _false_positives(boxes: np.ndarray, confs: np.ndarray, of: dict[str, np.ndarray], truth: Sequence[Any],
                     iou_threshold: float, fp_conf: float) -> int:
    """Confident detections of an actor class overlapping no ground truth of that kind, plus confident
    detections of any other class."""
    confident = confs >= fp_conf
    unmatched = confident.copy()
    for kind, is_kind in of.items():
        overlap = np.zeros(len(boxes))
        for t in truth:
            if kind_of(t) == kind:
                overlap = np.maximum(overlap, target_iou(boxes, t, "either"))
        unmatched &= ~(is_kind & (overlap >= iou_threshold))
    return int(unmatched.sum())


def _boxes_of(truth: Any) -> tuple[Box | None, Box | None]:
    if hasattr(truth, "full_box"):
        return _box(truth.full_box), _box(getattr(truth, "visible_box", None))
    box = _box(truth)
    return box, box


def _box(value: Any) -> Box | None:
    """A usable xyxy box, or None for a missing one (no pixels, out of view)."""
    if value is None or len(value) == 0:
        return None
    x1, y1, x2, y2 = (float(v) for v in value)
    return (x1, y1, x2, y2)
