"""Synthetic bird's-eye views of one row of bays, with their truth: what the `lines` baseline was tuned on and
what its tests and its table in docs/slot_detector.md measure (no rendering).

The ego stands at the image centre (blacked out, as a surround BEV shows it), in a dark asphalt lane; the row
of perpendicular bays (lighter floor, white lines) opens onto the lane 2.0-2.8 m beside it, turned to a random
side and tilted up to 15 degrees. Floor noise, a lighting gradient, a dashed yellow centre line, parked cars
as dark rounded boxes with a lighter windscreen. Wear fades the paint towards the floor and drops pieces of it
(0.25 m long, each with probability wear / 2), as the `wear` group does to the rendered garage.
"""

from __future__ import annotations

import math

import numpy as np

from garage_exp.slots.marks import MarkingPoint, Slot, SlotFrame

ASPHALT = np.array([62.0, 62.0, 66.0])
BAY_FLOOR = np.array([118.0, 114.0, 104.0])
PAINT = np.array([225.0, 225.0, 218.0])
YELLOW = np.array([200.0, 170.0, 40.0])
PIECE = 0.25  # metres: worn paint goes in pieces this long


def bev_row(seed: int, *, mpp: float = 0.02, size: int = 640, bays: int = 4, bay_width: float = 2.5,
            depth: float = 5.3, line_width: float = 0.15, entrance_line: bool = False,
            occupied: tuple[int, ...] = (1,), wear: float = 0.0, noise: float = 6.0,
            gain: float = 1.0) -> tuple[np.ndarray, SlotFrame]:
    """(RGB uint8 image size x size, truth): a row of `bays` bays; the bays numbered in `occupied` hold a car.
    gain scales the light before the noise is added (0.35: a dim garage, the same noise on a third of the
    signal)."""
    import cv2

    rng = np.random.default_rng(seed)
    theta = rng.integers(4) * math.pi / 2 + math.radians(rng.uniform(-15, 15))
    rot = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    centre = np.array([size / 2, size / 2])
    entrance = rng.uniform(2.0, 2.8)
    x0 = -bays * bay_width / 2 + rng.uniform(-0.5, 0.5)

    def px(points) -> np.ndarray:
        """Local metres (x along the lane, y across it, into the bays) to image pixels."""
        return centre + (np.asarray(points, np.float64) @ rot.T) / mpp

    def fill(image: np.ndarray, local, colour) -> None:
        cv2.fillConvexPoly(image, np.round(px(local) * 16).astype(np.int32), [float(c) for c in colour],
                           lineType=cv2.LINE_AA, shift=4)

    def rect(xa: float, ya: float, xb: float, yb: float) -> list[tuple[float, float]]:
        return [(xa, ya), (xb, ya), (xb, yb), (xa, yb)]

    big = 4 * size * mpp
    image = np.zeros((size, size, 3), np.float32)
    fill(image, rect(-big, -big, big, entrance), ASPHALT)
    fill(image, rect(-big, entrance, big, big), BAY_FLOOR)
    for s in np.arange(-big, big, 3.0):  # the lane's dashed centre line
        fill(image, rect(s, -0.06, s + 1.5, 0.06), YELLOW)
    paint = BAY_FLOOR + (PAINT - BAY_FLOOR) * (1 - 0.6 * wear)
    half = line_width / 2
    xs = [x0 + k * bay_width for k in range(bays + 1)]
    pieces = [(x - half, entrance, x + half, entrance + depth) for x in xs]
    if entrance_line:
        pieces.append((xs[0] - half, entrance - half, xs[-1] + half, entrance + half))
    for xa, ya, xb, yb in pieces:
        along_x = xb - xa > yb - ya
        a, b = (xa, xb) if along_x else (ya, yb)
        for s in np.arange(a, b, PIECE):
            if rng.uniform() < wear / 2:
                continue
            e = min(b, s + PIECE)
            fill(image, rect(s, ya, e, yb) if along_x else rect(xa, s, xb, e), paint)
    for k in occupied:
        cx = x0 + (k + 0.5) * bay_width + rng.uniform(-0.15, 0.15)
        cy = entrance + depth / 2 + rng.uniform(-0.2, 0.2)
        body = np.array([rng.uniform(25, 60)] * 3) + rng.uniform(-10, 10, 3)
        fill(image, rect(cx - 0.9, cy - 2.2, cx + 0.9, cy + 2.2), body)
        fill(image, rect(cx - 0.75, cy - 1.3, cx + 0.75, cy - 0.6), body + 70)  # windscreen
    gradient = np.linspace(0.85, 1.1, size)[None, :, None] * np.linspace(1.05, 0.9, size)[:, None, None]
    image = image * gradient * gain + rng.normal(0, noise, image.shape)
    fill(image, rect(-2.4, -0.95, 2.4, 0.95), (0, 0, 0))  # the ego: no camera sees under it
    image = np.clip(image, 0, 255).astype(np.uint8)
    return image, truth_row(xs, entrance, depth, occupied, px, theta, size, mpp)


def truth_row(xs, entrance: float, depth: float, occupied, px, theta: float, size: int, mpp: float) -> SlotFrame:
    """Marking points where each separating line meets the entrance, pointing into the bays; slots ordered as
    the baseline orders them (clockwise of p1 -> p2 on the image)."""
    direction = theta + math.pi / 2  # local +y, into the bays
    points = []
    for k, x in enumerate(xs):
        col, row = px([(x, entrance)])[0]
        points.append(MarkingPoint(float(col), float(row), math.atan2(math.sin(direction), math.cos(direction)),
                                   "L" if k in (0, len(xs) - 1) else "T"))
    d = np.array([math.cos(direction), math.sin(direction)])
    slots = []
    for k in range(len(xs) - 1):
        a, b = np.array([points[k].x, points[k].y]), np.array([points[k + 1].x, points[k + 1].y])
        v = b - a
        p1, p2 = (k, k + 1) if d[0] * v[1] - d[1] * v[0] < 0 else (k + 1, k)
        a, b = np.array([points[p1].x, points[p1].y]), np.array([points[p2].x, points[p2].y])
        back = depth / mpp * d
        corners = tuple((float(c[0]), float(c[1])) for c in (a, b, b + back, a + back))
        slots.append(Slot(p1, p2, corners, occupied=k in occupied, bay=f"bay_{k}"))
    return SlotFrame(points, slots, float(mpp), (size, size))
