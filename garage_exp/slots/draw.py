"""Marking points and slots drawn on a BEV image, to look at (a SlotFrame over its own image)."""

from __future__ import annotations

import math

import numpy as np

from garage_exp.slots.marks import SlotFrame

TRUTH = (0, 220, 0)  # RGB
FOUND = (255, 40, 200)
FREE, OCCUPIED = (0, 200, 255), (255, 120, 0)


def draw_slots(image: np.ndarray, frame: SlotFrame, colour=FOUND, thick: int = 2, arrow: float = 0.6) -> np.ndarray:
    """A copy of `image` (RGB) with the frame's slots (quads; the entrance line thicker, its occupancy as a dot
    in the quad: orange occupied, cyan free) and marking points (circles with an arrow `arrow` metres long along
    their direction)."""
    import cv2

    out = np.ascontiguousarray(image[..., :3]).copy()
    scale = 16  # cv2's fixed-point shift 4: sub-pixel drawing

    def fx(x: float, y: float) -> tuple[int, int]:
        return int(round(x * scale)), int(round(y * scale))

    for slot in frame.slots:
        quad = [fx(*c) for c in slot.corners]
        cv2.polylines(out, [np.array(quad, np.int32)], True, colour, 1, cv2.LINE_AA, shift=4)
        cv2.line(out, quad[0], quad[1], colour, thick + 1, cv2.LINE_AA, shift=4)
        if slot.occupied is not None:
            cx, cy = np.mean(slot.corners, axis=0)
            cv2.circle(out, fx(cx, cy), 6 * scale, OCCUPIED if slot.occupied else FREE, -1, cv2.LINE_AA, shift=4)
            cv2.circle(out, fx(cx, cy), 6 * scale, colour, 1, cv2.LINE_AA, shift=4)
    length = arrow / frame.meters_per_pixel
    for q in frame.points:
        tip = (q.x + length * math.cos(q.direction), q.y + length * math.sin(q.direction))
        cv2.circle(out, fx(q.x, q.y), 5 * scale, colour, thick, cv2.LINE_AA, shift=4)
        cv2.arrowedLine(out, fx(q.x, q.y), fx(*tip), colour, thick, cv2.LINE_AA, shift=4, tipLength=0.25)
    return out
