"""Cell classification by counting driveable 4-neighbours, and the pillar grid at cell corners."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from garage_exp.core.state import STATE
from garage_exp.plan.model import DRIVEABLE, ENTRANCE, EXIT, LANE, OBSTACLE, OPPOSITE, PARKING, YAW, Plan

KIND = {OBSTACLE: "obstacle", PARKING: "parking", LANE: "lane", ENTRANCE: "entrance", EXIT: "exit"}
LANE_TYPES = ("straight", "corner", "t_junction", "crossroads")
PARKING_TYPES = ("type1", "type2", "type3", "type4")


@dataclass(frozen=True)
class Cell:
    i: int
    j: int
    value: int
    kind: str  # obstacle | parking | lane | entrance | exit
    type: str  # lanes/entrances/exits: LANE_TYPES; parking: PARKING_TYPES; obstacle: ""
    lanes: tuple[str, ...]  # directions (N, E, S, W) of driveable neighbours
    rotation: float  # degrees CCW from +x; see `_rotation`

    @property
    def driveable(self) -> bool:
        return self.value in DRIVEABLE


@dataclass(frozen=True)
class Classified:
    plan: Plan
    cells: tuple[tuple[Cell, ...], ...]
    pillars: tuple["Pillar", ...]

    def cell(self, i: int, j: int) -> Cell:
        return self.cells[i][j]

    def all_cells(self):
        for row in self.cells:
            yield from row

    def of_type(self, *types: str) -> list[Cell]:
        return [c for c in self.all_cells() if c.type in types or c.kind in types]


def _lane_type(lanes: tuple[str, ...]) -> str:
    k = len(lanes)
    if k == 4:
        return "crossroads"
    if k == 3:
        return "t_junction"
    if k == 2 and OPPOSITE[lanes[0]] != lanes[1]:
        return "corner"
    return "straight"


def _parking_type(lanes: tuple[str, ...]) -> str:
    k = len(lanes)
    if k >= 3 or (k == 2 and OPPOSITE[lanes[0]] == lanes[1]):
        return "type1"
    return {2: "type2", 1: "type3", 0: "type4"}[k]


def _rotation(kind: str, ctype: str, lanes: tuple[str, ...]) -> float:
    """Parking, entrance, exit: yaw towards the (first) lane. Straight lanes: yaw of the lane axis
    (0 or 90). Corners: yaw of the bisector between the two lane directions. T-junctions: yaw of the
    stem (away from the blocked side). Crossroads: 0."""
    if not lanes:
        return 0.0
    if kind == "parking" or kind in ("entrance", "exit"):
        return YAW[lanes[0]]
    if ctype == "straight":
        return YAW[lanes[0]] % 180.0
    if ctype == "corner":
        a, b = sorted(YAW[d] for d in lanes)
        return (a + b) / 2 if b - a < 180 else ((a + b) / 2 + 180) % 360
    if ctype == "t_junction":
        missing = next(d for d in "NESW" if d not in lanes)
        return YAW[OPPOSITE[missing]]
    return 0.0


def classify_cell(plan: Plan, i: int, j: int) -> Cell:
    value = int(plan.S[i, j])
    kind = KIND[value]
    lanes = tuple(d for d, a, b in plan.neighbours(i, j) if int(plan.S[a, b]) in DRIVEABLE)
    if kind == "obstacle":
        ctype = ""
    elif kind == "parking":
        ctype = _parking_type(lanes)
    else:
        ctype = _lane_type(lanes)
    return Cell(i, j, value, kind, ctype, lanes, _rotation(kind, ctype, lanes))


@dataclass(frozen=True)
class Pillar:
    """A pillar at grid vertex (a, b) (see Plan.vertex), shifted by (sx, sy) half pillar sizes so that it
    stands inside the non-driveable cells around the vertex and never in a lane."""

    a: int
    b: int
    sx: int  # -1, 0 or +1: shift along x in units of half the pillar size
    sy: int


# Quadrants around a vertex as (row offset, column offset, x side, y side): NW is row a-1, column b-1.
_QUADRANTS = ((-1, -1, -1, 1), (-1, 0, 1, 1), (0, -1, -1, -1), (0, 0, 1, -1))
_SHIFTS = sorted(((sx, sy) for sx in (-1, 0, 1) for sy in (-1, 0, 1)), key=lambda s: abs(s[0]) + abs(s[1]))


def _overlaps(shift: int, side: int) -> bool:
    # A square of half size h shifted by shift*h spans (shift-1)h..(shift+1)h; it reaches into the
    # quadrant on `side` unless it lies wholly on the other side.
    return shift != -side


def pillar_vertices(plan: Plan) -> list[Pillar]:
    """Interior grid vertices that touch a parking cell, each with the smallest shift that keeps the
    pillar off every driveable cell. The perimeter carries walls instead."""
    S = plan.S
    m, n = S.shape
    drive = np.isin(S, DRIVEABLE)
    out = []
    for a in range(1, m):
        for b in range(1, n):
            quads = [(a + di, b + dj, xs, ys) for di, dj, xs, ys in _QUADRANTS]
            if not any(S[i, j] == PARKING for i, j, _, _ in quads):
                continue
            blocked = [(xs, ys) for i, j, xs, ys in quads if drive[i, j]]
            for sx, sy in _SHIFTS:
                if not any(_overlaps(sx, xs) and _overlaps(sy, ys) for xs, ys in blocked):
                    out.append(Pillar(a, b, sx, sy))
                    break
    return out


def classify(plan: Plan) -> Classified:
    return _classify_cached(plan)


@STATE.memo("process", maxsize=16)
def _classify_cached(plan: Plan) -> Classified:
    m, n = plan.shape
    cells = tuple(tuple(classify_cell(plan, i, j) for j in range(n)) for i in range(m))
    return Classified(plan, cells, tuple(pillar_vertices(plan)))
