"""The `slot_detector` group's schema, beside its check (slots/detector.check_slot_detector), registered
as a config node here (core/config_nodes.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from garage_exp.core.config_nodes import register_node


@dataclass
class SlotLinesConf:
    """The `lines` baseline's settings (garage_exp/slots/lines.py), in metres where lengths."""

    line_width: tuple[float, float] = (0.08, 0.25)  # painted line widths it looks for
    min_contrast: float = 20.0  # paint at least this much brighter than the floor beside it (0-255 grey levels)
    min_line: float = 1.0  # the shortest painted run kept as a separating line
    max_gap: float = 0.8  # gaps in worn paint bridged along a line
    bay_width: tuple[float, float] = (2.2, 3.2)  # entrance width: two marking points this far apart open a slot
    depth: tuple[float, float] = (4.5, 6.0)  # a slot's depth; the middle when the back of the bay is not seen
    junction: float = 0.6  # a separating line ending this near an entrance line meets it (a T or an L; worn ends)
    parallel_deg: float = 10.0  # lines within this angle are parallel
    border: float = 0.2  # a line end this near the image edge or unseen (black) pixels is cut, not an end
    occupied_delta: float = 0.35  # not floor: this far from the floor's colour (RGB distance / the colour's length)
    occupied_fraction: float = 0.3  # a slot is occupied when this share of its inner part is not floor


@dataclass
class SlotMetricsConf:
    """PS2.0's matching tolerances (garage_exp/slots/results.py). PS2.0 images are 600 px for 10 m, and a
    marking point matches within 10 px (0.167 m) and 30 degrees."""

    point_tolerance_m: float = 0.17
    angle_tolerance_deg: float = 30.0
    min_score: float = 0.0  # found points and slots scoring lower are dropped before matching


@dataclass
class SlotDetectorConf:
    """The slot detector run on the BEV (garage_exp/slots/detector.py): `lines`, the classical
    baseline (no weights); `callable`, the user's function `detect: {_target_: package.module.function, ...}`
    (called with the BEV RGB image and its metres per pixel, then the node's other keys, returning a SlotFrame); `pose`, an ultralytics pose model `model`
    (.pt) whose keypoints are a slot's four corners (`keypoints: corners`) or a marking point and a point along
    its direction (`keypoints: points`)."""

    name: str = "lines"
    kind: str = "lines"  # a registered kind (slots/detector.py KINDS): lines | callable | pose
    detect: Any = None  # callable: {_target_: package.module.function, ...its keyword arguments}
    target: str = ""  # the old form of `detect` ("package.module:function"): refused, naming the new one
    model: str = ""  # pose: path to the .pt
    keypoints: str = "corners"  # pose: corners | points
    conf: float = 0.25  # pose: the model's confidence threshold
    imgsz: int = 640  # pose: the model's input size
    lines: SlotLinesConf = field(default_factory=SlotLinesConf)
    metrics: SlotMetricsConf = field(default_factory=SlotMetricsConf)


register_node("slot_detector", SlotDetectorConf, group=True)
