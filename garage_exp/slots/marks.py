"""What slot ground truth and slot detectors exchange: marking points and slots on one bird's-eye-view image.

Coordinates are BEV pixels with the project's convention (pixel (col, row) spans [col, col+1) x [row, row+1)); a
`SlotFrame` carries its metres per pixel, so tolerances can be given in metres. The vocabulary is PS2.0's
(Zhang et al., 2018; DMPR-PS, Huang et al., 2019): a marking point is where a bay's separating line meets the
entrance line; its direction points along the separating line, into the slot; a slot is a pair of marking points
(its entrance line) and the quad they open.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class MarkingPoint:
    x: float  # column, BEV pixels
    y: float  # row, BEV pixels
    direction: float  # radians in the image frame, atan2(d_row, d_col): along the separating line, into the slot
    shape: str = "T"  # "T": the entrance line goes on past the point; "L": the end of a row of bays
    score: float = 1.0  # a detector's confidence; 1 for ground truth


@dataclass(frozen=True)
class Slot:
    p1: int  # index into SlotFrame.points: the entrance's first marking point
    p2: int  # the second; p1 -> p2 runs along the entrance line
    corners: tuple[tuple[float, float], ...]  # (col, row) x 4: entrance p1, entrance p2, back of p2, back of p1
    occupied: bool | None = None  # None: the detector does not say
    score: float = 1.0
    bay: str = ""  # ground truth: the bay's id in the scene


@dataclass
class SlotFrame:
    """One BEV image's marking points and slots."""

    points: list[MarkingPoint] = field(default_factory=list)
    slots: list[Slot] = field(default_factory=list)
    meters_per_pixel: float = 0.02
    size: tuple[int, int] = (500, 500)  # (width, height) of the BEV image, pixels
