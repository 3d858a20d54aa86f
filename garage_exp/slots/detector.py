"""The slot detector a job runs on its bird's-eye views, from the `slot_detector` config group.

`load(conf)` returns `detect(image, meters_per_pixel) -> SlotFrame` (image: BEV RGB uint8 (H, W, 3)) of the
node's kind (`slot_detector.kind`). The kinds are a registry, each registered beside its class with
`@register_slot_kind(NAME)` (a `SlotKind`: `check`, `weights`, `load`), so adding one is one module with its class:
- `lines`: the classical baseline (garage_exp/slots/lines.py), no weights;
- `callable`: the user's function, named by `detect._target_` like every component a config names and built the
  project's one way (core.plugins.build, as a partial: the node's other keys are its keyword arguments; the
  module must lie under garage_exp. or a prefix in $GARAGE_EXP_MODIFIER_MODULES);
- `pose`: an ultralytics pose model (`model`, a .pt) whose keypoints are mapped by `from_pose` below.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from garage_exp.core.errors import GarageError, check_range, did_you_mean
from garage_exp.core.plain import plain
from garage_exp.slots.marks import MarkingPoint, Slot, SlotFrame

KEYPOINTS = ("corners", "points")
Detect = Callable[[np.ndarray, float], SlotFrame]
KINDS: dict[str, type] = {}  # slot_detector.kind -> its SlotKind class (`@register_slot_kind`)


def register_slot_kind(name: str) -> Callable:
    """Register a `SlotKind` class under `name` (`slot_detector.kind`)."""
    def register(cls: type) -> type:
        KINDS[name] = cls
        return cls
    return register


class SlotKind:
    """A kind of slot detector: its own config check (after the node's shared keys are checked), its files (a real
    job's preflight, beside the object detector's weights) and the detector itself."""

    @staticmethod
    def check(conf: Any) -> None:
        """The kind's own keys (GarageError naming the key)."""

    @staticmethod
    def weights(conf: Any) -> None:
        """The kind's files are there."""

    @staticmethod
    def load(conf: Any) -> Detect:
        raise NotImplementedError


def check_slot_detector(conf: Any) -> None:
    """The `slot_detector` group's values; a callable's module is imported here (a pose model's file is looked
    for by check_slot_weights)."""
    kind = str(conf.kind)
    if kind not in KINDS:
        raise GarageError(f"unknown kind {kind!r}{did_you_mean(kind, KINDS)}", "slot_detector.kind")
    p = conf.lines
    for key in ("line_width", "bay_width", "depth"):
        lo, hi = (float(v) for v in getattr(p, key))
        if not 0 < lo <= hi:
            raise GarageError(f"[{lo:g}, {hi:g}] is not a range of positive metres (low <= high)",
                              f"slot_detector.lines.{key}")
    check_range(p.line_width[1], 0.01, 1.0, "slot_detector.lines.line_width")
    check_range(p.min_contrast, 1, 255, "slot_detector.lines.min_contrast")
    for key in ("min_line", "max_gap", "junction", "border"):
        check_range(getattr(p, key), 0.0, 20.0, f"slot_detector.lines.{key}")
    check_range(p.parallel_deg, 0.1, 45, "slot_detector.lines.parallel_deg")
    check_range(p.occupied_delta, 0.01, 2.0, "slot_detector.lines.occupied_delta")
    check_range(p.occupied_fraction, 0.0, 1.0, "slot_detector.lines.occupied_fraction")
    m = conf.metrics
    if not float(m.point_tolerance_m) > 0:
        raise GarageError(f"{m.point_tolerance_m} is not a positive distance (metres)",
                          "slot_detector.metrics.point_tolerance_m")
    check_range(m.angle_tolerance_deg, 0.0, 180.0, "slot_detector.metrics.angle_tolerance_deg")
    check_range(m.min_score, 0.0, 1.0, "slot_detector.metrics.min_score")
    KINDS[kind].check(conf)


def check_slot_weights(conf: Any) -> None:
    """The kind's files are there (a pose model's .pt; a real job's preflight, beside the object detector's)."""
    KINDS[str(conf.kind)].weights(conf)


def user_function(conf: Any) -> Detect:
    """The function `slot_detector.detect` names (`_target_`, through the plugin allow-list), with the node's
    other keys as its keyword arguments."""
    from garage_exp.core.plugins import build, resolve

    if str(conf.get("target") or ""):  # the old form, "package.module:function"
        module, _, name = str(conf.target).partition(":")
        raise GarageError(f"slot_detector.target is gone: name the function as slot_detector.detect._target_="
                          f"{module}{'.' if name else ''}{name}", "slot_detector.target")
    node = conf.get("detect")
    target = str(node.get("_target_") or "") if node else ""
    if not target:
        raise GarageError("kind callable needs detect._target_ (package.module.function)",
                          "slot_detector.detect._target_")
    if not callable(resolve(target, "a slot detector", "slot_detector.detect._target_")):
        raise GarageError(f"{target!r} is not a function", "slot_detector.detect._target_")
    return build(node, "a slot detector", "slot_detector.detect", _partial_=True)


def load(conf: Any) -> Detect:
    """The detector the `slot_detector` node describes (checked first)."""
    check_slot_detector(conf)
    check_slot_weights(conf)
    return KINDS[str(conf.kind)].load(conf)


@register_slot_kind("lines")
class Lines(SlotKind):
    """The classical baseline (slots/lines.py), no weights."""

    @staticmethod
    def load(conf: Any) -> Detect:
        from garage_exp.slots.lines import detect as detect_lines
        from garage_exp.slots.schema import SlotLinesConf

        # plain attribute reads in the detector's loops (a config node's are slow); missing keys take the defaults
        params = conf.lines if isinstance(conf.lines, SlotLinesConf) else SlotLinesConf(**plain(conf.lines))
        return lambda image, mpp: detect_lines(image, float(mpp), params)


@register_slot_kind("callable")
class UserCallable(SlotKind):
    """The user's function, `detect._target_` (`user_function`)."""

    @staticmethod
    def check(conf: Any) -> None:
        user_function(conf)

    @staticmethod
    def load(conf: Any) -> Detect:
        target = str(conf.detect._target_)
        function = user_function(conf)

        def detect_user(image: np.ndarray, mpp: float) -> SlotFrame:
            out = function(image, float(mpp))
            if not isinstance(out, SlotFrame):
                raise GarageError(f"returned {type(out).__name__}, not a SlotFrame", f"slot_detector.detect._target_ {target}")
            return out

        return detect_user


@register_slot_kind("pose")
class PoseModel(SlotKind):
    """An ultralytics pose model (`model`, a .pt) whose keypoints are mapped by `from_pose`."""

    @staticmethod
    def check(conf: Any) -> None:
        if str(conf.keypoints) not in KEYPOINTS:
            raise GarageError(f"unknown keypoints {conf.keypoints!r}{did_you_mean(str(conf.keypoints), KEYPOINTS)}",
                              "slot_detector.keypoints")
        check_range(conf.conf, 0.0, 1.0, "slot_detector.conf")
        check_range(conf.imgsz, 32, 4096, "slot_detector.imgsz")

    @staticmethod
    def weights(conf: Any) -> None:
        path = Path(str(conf.model)).expanduser()
        if not str(conf.model) or path.suffix != ".pt" or not path.is_file():
            raise GarageError(f"{str(conf.model)!r} is not an ultralytics pose model file (.pt)",
                              "slot_detector.model")

    @staticmethod
    def load(conf: Any) -> Detect:
        return pose_detector(conf)


def pose_detector(conf: Any) -> Detect:
    """An ultralytics pose model, its keypoints mapped by `from_pose`."""
    from ultralytics import YOLO

    path = str(Path(str(conf.model)).expanduser())
    try:
        model = YOLO(path)
    except Exception as exc:  # ultralytics and torch raise many types; one line naming the file
        raise GarageError(f"not a model ultralytics can load ({type(exc).__name__}: {str(exc)[:200]})",
                          f"slot_detector.model {path}") from None
    if getattr(model, "task", None) != "pose":
        raise GarageError(f"a {getattr(model, 'task', '?')} model, not a pose (keypoint) model",
                          f"slot_detector.model {path}")
    keypoints, lines, threshold, imgsz = str(conf.keypoints), conf.lines, float(conf.conf), int(conf.imgsz)

    def detect_pose(image: np.ndarray, mpp: float) -> SlotFrame:
        result = model.predict(np.ascontiguousarray(image[..., ::-1]), conf=threshold, imgsz=imgsz, verbose=False)[0]
        return from_pose(result, keypoints, float(mpp), (int(image.shape[1]), int(image.shape[0])), lines)

    return detect_pose


def _numpy(x: Any) -> np.ndarray:
    """A torch tensor or an array as a numpy array."""
    if hasattr(x, "cpu"):
        x = x.cpu()
    return np.asarray(x.numpy() if hasattr(x, "numpy") else x, dtype=np.float64)


def _occupied(names: dict, cls: float) -> bool | None:
    name = str(names.get(int(cls), "")).lower()
    return True if name in ("occupied", "taken", "full") else False if name in ("free", "empty", "vacant") else None


def from_pose(result: Any, keypoints: str, mpp: float, size: tuple[int, int], lines: Any) -> SlotFrame:
    """An ultralytics pose `Results` (keypoints.xy (N, K, 2), boxes.conf and .cls, names) as a SlotFrame.
    corners: each object a slot, K >= 4 keypoints: entrance p1, entrance p2, back of p2, back of p1; its entrance
    points become marking points (one per place: points within a quarter bay width are one), pointing from the
    entrance to the back; classes named free/occupied give its occupancy.
    points: each object a marking point, K >= 2: the point and a point along its direction; a class named T or L
    gives its shape; slots are paired as the lines baseline pairs them (lines.bay_width, lines.depth)."""
    from garage_exp.slots.lines import pair_points

    xy = _numpy(result.keypoints.xy) if result.keypoints is not None else np.zeros((0, 0, 2))
    n = len(xy)
    scores = _numpy(result.boxes.conf) if n else np.zeros(0)
    classes = _numpy(result.boxes.cls) if n else np.zeros(0)
    names = dict(getattr(result, "names", {}) or {})
    need = 4 if keypoints == "corners" else 2
    if n and xy.shape[1] < need:
        raise GarageError(f"the model gives {xy.shape[1]} keypoints per object; keypoints={keypoints} needs {need}",
                          "slot_detector.keypoints")
    points: list[MarkingPoint] = []
    if keypoints == "points":
        for k in range(n):
            (x, y), (x2, y2) = xy[k, 0], xy[k, 1]
            shape = str(names.get(int(classes[k]), "T"))
            points.append(MarkingPoint(float(x), float(y), math.atan2(y2 - y, x2 - x),
                                       shape if shape in ("T", "L") else "T", float(scores[k])))
        return SlotFrame(points, pair_points(points, mpp, lines), mpp, size)
    merge = 0.25 * float(lines.bay_width[0]) / mpp
    slots: list[Slot] = []

    def point(at: np.ndarray, towards: np.ndarray, score: float) -> int:
        for k, q in enumerate(points):
            if math.hypot(q.x - at[0], q.y - at[1]) <= merge:
                if score > q.score:
                    points[k] = MarkingPoint(q.x, q.y, q.direction, q.shape, score)
                return k
        d = towards - at
        points.append(MarkingPoint(float(at[0]), float(at[1]), math.atan2(d[1], d[0]), "T", score))
        return len(points) - 1

    for k in range(n):
        c = xy[k, :4]
        score = float(scores[k])
        p1, p2 = point(c[0], c[3], score), point(c[1], c[2], score)
        slots.append(Slot(p1, p2, tuple((float(x), float(y)) for x, y in c), _occupied(names, classes[k]), score))
    return SlotFrame(points, slots, mpp, size)
