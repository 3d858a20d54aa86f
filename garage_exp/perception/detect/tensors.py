"""A detection network's tensors in and out, for models run outside ultralytics (a model server's).

In: frames are letterboxed to the network's fixed input size as ultralytics does (scaled to fit, centred, grey
114 padding) or sent as they are when the network takes any size. Out: one of three layouts, per frame
- `three`: boxes K x 4 (x1, y1, x2, y2 in input pixels), scores K, classes K (class indices); rows whose
  score is <= 0 are padding (a fixed K with fewer detections);
- `end2end`: K x 6 rows (x1, y1, x2, y2, score, class): an NMS-free or NMS-included export (yolo26, YOLOv10);
- `raw`: (4 + C) x A, ultralytics' detection head before NMS (cx, cy, w, h, then C class scores per anchor);
  NMS is done here as ultralytics does it (best class per anchor, class-aware, IoU 0.7, 300 at most).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LAYOUTS = ("three", "end2end", "raw")
PAD_VALUE = 114  # ultralytics' letterbox grey
NMS_IOU = 0.7  # ultralytics' predict default
MAX_DET = 300


@dataclass
class Letterbox:
    """How a frame was fitted into the network input: scale, then (left, top) padding."""

    gain: float = 1.0
    left: int = 0
    top: int = 0

    def unmap(self, boxes: np.ndarray, width: int, height: int) -> np.ndarray:
        """Boxes in network-input pixels -> the original frame's pixels, clipped to it."""
        out = boxes.astype(np.float32).copy()
        out[:, [0, 2]] = (out[:, [0, 2]] - self.left) / self.gain
        out[:, [1, 3]] = (out[:, [1, 3]] - self.top) / self.gain
        out[:, [0, 2]] = out[:, [0, 2]].clip(0, width)
        out[:, [1, 3]] = out[:, [1, 3]].clip(0, height)
        return out


def letterbox(rgb: np.ndarray, height: int, width: int) -> tuple[np.ndarray, Letterbox]:
    """The frame scaled to fit height x width, centred on grey (ultralytics' LetterBox, auto=False)."""
    import cv2

    h0, w0 = rgb.shape[:2]
    if (h0, w0) == (height, width):
        return rgb, Letterbox()
    gain = min(height / h0, width / w0)
    new_w, new_h = int(round(w0 * gain)), int(round(h0 * gain))
    dw, dh = (width - new_w) / 2, (height - new_h) / 2
    resized = cv2.resize(rgb, (new_w, new_h), interpolation=cv2.INTER_LINEAR) if (new_w, new_h) != (w0, h0) else rgb
    top, left = int(round(dh - 0.1)), int(round(dw - 0.1))
    bottom, right = int(round(dh + 0.1)), int(round(dw + 0.1))
    padded = cv2.copyMakeBorder(resized, top, bottom, left, right, cv2.BORDER_CONSTANT, value=(PAD_VALUE,) * 3)
    return padded, Letterbox(gain, left, top)


def layout_of(shapes: dict[str, list[int]], classes: int) -> str:
    """Which layout a model's output shapes (batch dimension first, -1 for any) are, or a sentence why none."""
    if len(shapes) == 3:
        dims = sorted(len(s) for s in shapes.values())
        if dims == [2, 2, 3] and any(s[-1] == 4 for s in shapes.values() if len(s) == 3):
            return "three"
        raise ValueError(f"three outputs must be boxes N x K x 4, scores N x K and classes N x K, got {shapes}")
    if len(shapes) == 1:
        (shape,) = shapes.values()
        if len(shape) == 3 and shape[2] == 6:
            return "end2end"
        if len(shape) == 3 and (shape[1] == 4 + classes or shape[1] == -1):
            return "raw"
        raise ValueError(f"one output must be N x K x 6 (x1, y1, x2, y2, score, class) or N x {4 + classes} x A "
                         f"(ultralytics' head for {classes} classes), got {list(shape)}")
    raise ValueError(f"expected one output (N x K x 6 or N x (4 + classes) x A) or three (boxes, scores, classes), "
                     f"got {len(shapes)}: {sorted(shapes)}")


def three_names(shapes: dict[str, list[int]]) -> tuple[str, str, str]:
    """The boxes, scores and classes outputs of the `three` layout: boxes by its last dimension 4, scores by
    name (`score` in it) or, failing that, by order."""
    boxes = next(n for n, s in shapes.items() if len(s) == 3)
    rest = [n for n in shapes if n != boxes]
    scores = next((n for n in rest if "score" in n.lower() or "conf" in n.lower()), rest[0])
    classes = next(n for n in rest if n != scores)
    return boxes, scores, classes


def decode(layout: str, outputs: dict[str, np.ndarray], conf: float, classes: int
           ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per frame of the batch: (boxes K x 4, scores K, class indices K) with score >= conf (and > 0).
    ValueError when the tensors do not have the layout's shapes (a server that answers the wrong thing)."""
    if layout == "three":
        names = three_names({n: list(a.shape) for n, a in outputs.items()})
        boxes, scores, cls = (np.asarray(outputs[n]) for n in names)
        n = boxes.shape[0]
        if boxes.ndim != 3 or boxes.shape[2] != 4 or scores.shape != boxes.shape[:2] or cls.shape != scores.shape:
            raise ValueError(f"boxes {list(boxes.shape)}, scores {list(scores.shape)}, classes {list(cls.shape)}: "
                             "expected N x K x 4, N x K, N x K")
        return [_keep(boxes[i], scores[i], cls[i], conf) for i in range(n)]
    (out,) = (np.asarray(a) for a in outputs.values())
    if layout == "end2end":
        if out.ndim != 3 or out.shape[2] != 6:
            raise ValueError(f"output {list(out.shape)}: expected N x K x 6")
        return [_keep(o[:, :4], o[:, 4], o[:, 5], conf) for o in out]
    if out.ndim != 3 or out.shape[1] != 4 + classes:
        raise ValueError(f"output {list(out.shape)}: expected N x {4 + classes} x A (ultralytics' head)")
    return [_nms(o, conf) for o in out]


def _keep(boxes, scores, cls, conf):
    boxes, scores, cls = (np.asarray(a, dtype=np.float32) for a in (boxes, scores, cls))
    keep = (scores >= conf) & (scores > 0)
    return boxes[keep].reshape(-1, 4), scores[keep], cls[keep].astype(np.int64)


def _nms(head: np.ndarray, conf: float):
    """ultralytics' non_max_suppression for one frame's raw head ((4 + C) x A): best class per anchor,
    class-aware NMS at IoU 0.7, the MAX_DET most confident kept."""
    import torch
    from torchvision.ops import batched_nms

    head = np.asarray(head, dtype=np.float32).T  # A x (4 + C)
    scores_all = head[:, 4:]
    cls = scores_all.argmax(1)
    scores = scores_all[np.arange(len(cls)), cls]
    keep = scores > conf
    xywh, scores, cls = head[keep, :4], scores[keep], cls[keep]
    boxes = np.concatenate([xywh[:, :2] - xywh[:, 2:] / 2, xywh[:, :2] + xywh[:, 2:] / 2], axis=1)
    if len(boxes) == 0:
        return boxes.reshape(0, 4), scores, cls.astype(np.int64)
    order = torch.from_numpy(scores).argsort(descending=True)[:30000]  # ultralytics' max_nms
    idx = batched_nms(torch.from_numpy(boxes)[order], torch.from_numpy(scores)[order], torch.from_numpy(cls)[order],
                      NMS_IOU)[:MAX_DET]
    picked = order[idx].numpy()
    return boxes[picked], scores[picked], cls[picked].astype(np.int64)
