"""Lane and bay paint as thin boxes on the floor, one entity per cell (role "marking").

- straight lanes: a dashed yellow centre line along the lane axis; dashes keep one phase over the whole
  plan so they line up from cell to cell.
- corners: the centre line bends through the cell centre (two dashed half-lines, one per lane side).
- T-junctions: a white stop line across the right-hand half of the stem where it meets the junction;
  crossroads: one on every approach. Right-hand traffic.
- bays (Type1-3): white lines perpendicular to the lane edge between the bays (see `bays.layout`).
Wear (garage.marking_wear, 0 fresh .. 1 gone) fades the paint towards the floor and removes a
deterministic share of the pieces (wear / 2); a piece removed at some wear stays removed at any higher wear.
"""

from __future__ import annotations

import math

from garage_exp.core.errors import GarageError
from garage_exp.plan.classify import Cell, Classified
from garage_exp.plan.features import UNIT
from garage_exp.scene import materials as mat
from garage_exp.scene.bays import BAY_TYPES, SIDE_OF_YAW, BayLayout, Rect, layout
from garage_exp.scene.description import Box, Entity, Material, Pose

PAINT_HEIGHT = 0.005  # top of the paint above the floor: enough to beat z-fighting, too thin to see
DASH, GAP = 1.5, 1.5
MIN_PIECE = 0.3  # dash pieces cut shorter than this at a cell edge are left out
STOP_WIDTH = 0.3
STOP_SETBACK = 0.3  # from the junction cell's edge
SIDE_MARGIN = 0.2  # paint stops this short of a cell's side
WEAR_SALT = 0x5EED
MASK = (1 << 64) - 1

Piece = tuple[Rect, Material, Material]  # rectangle, paint, floor under it


def unit_hash(*keys: int) -> float:
    """A stable number in [0, 1) per key tuple (a splitmix64 mix): which pieces wear away does not depend
    on the order they are built in."""
    h = WEAR_SALT
    for k in keys:
        h = (h ^ (k & MASK)) * 0x9E3779B97F4A7C15 & MASK
        h = (h ^ (h >> 30)) * 0xBF58476D1CE4E5B9 & MASK
        h = (h ^ (h >> 27)) * 0x94D049BB133111EB & MASK
        h ^= h >> 31
    return h / float(1 << 64)


def dashes(a: float, b: float) -> list[tuple[float, float]]:
    """Dash intervals of the global pattern [k*P, k*P + DASH] clipped to [a, b]."""
    period = DASH + GAP
    out = []
    k = math.floor(a / period)
    while k * period < b - 1e-9:
        s, e = max(a, k * period), min(b, k * period + DASH)
        if e - s >= MIN_PIECE:
            out.append((s, e))
        k += 1
    return out


def dashed_line(axis: str, a: float, b: float, at: float, width: float) -> list[Rect]:
    h = width / 2
    if axis == "x":
        return [(s, at - h, e, at + h) for s, e in dashes(a, b)]
    return [(at - h, s, at + h, e) for s, e in dashes(a, b)]


def stop_line(rect: Rect, side: str) -> Rect:
    """Across the right-hand half of the lane that enters the cell from `side`, set back from that edge."""
    x0, y0, x1, y1 = rect
    xc, yc = (x0 + x1) / 2, (y0 + y1) / 2
    ux, uy = UNIT[side]
    rx, ry = -uy, ux  # right-hand side of a car driving in, heading (-ux, -uy)
    inset = STOP_SETBACK + STOP_WIDTH / 2
    if side in ("E", "W"):
        xm = (x1 if side == "E" else x0) - ux * inset
        far = yc + ry * ((y1 - y0) / 2 - SIDE_MARGIN)
        return (xm - STOP_WIDTH / 2, min(yc, far), xm + STOP_WIDTH / 2, max(yc, far))
    ym = (y1 if side == "N" else y0) - uy * inset
    far = xc + rx * ((x1 - x0) / 2 - SIDE_MARGIN)
    return (min(xc, far), ym - STOP_WIDTH / 2, max(xc, far), ym + STOP_WIDTH / 2)


def lane_pieces(classified: Classified, cell: Cell, width: float) -> list[Piece]:
    rect = classified.plan.cell_rect(cell.i, cell.j)
    x0, y0, x1, y1 = rect
    xc, yc = (x0 + x1) / 2, (y0 + y1) / 2
    lines: list[Rect] = []
    stops: list[Rect] = []
    if cell.type == "straight":
        if cell.rotation % 180.0 == 0.0:
            lines = dashed_line("x", x0, x1, yc, width)
        else:
            lines = dashed_line("y", y0, y1, xc, width)
    elif cell.type == "corner":
        half = {"E": ("x", xc, x1, yc), "W": ("x", x0, xc, yc), "N": ("y", yc, y1, xc), "S": ("y", y0, yc, xc)}
        for d in cell.lanes:
            axis, a, b, at = half[d]
            lines += dashed_line(axis, a, b, at, width)
    elif cell.type == "t_junction":
        stops = [stop_line(rect, SIDE_OF_YAW[cell.rotation % 360.0])]
    elif cell.type == "crossroads":
        stops = [stop_line(rect, d) for d in cell.lanes]
    return ([(r, mat.LANE_YELLOW, mat.ASPHALT) for r in lines]
            + [(r, mat.LANE_WHITE, mat.ASPHALT) for r in stops])


def _drawn_by_neighbour(classified: Classified, lay: BayLayout) -> bool:
    """The next bay cell along the lane edge with the same facing draws the shared line (as its first)."""
    i, j = lay.cell.i, lay.cell.j
    ni, nj = (i, j + 1) if lay.along_x else (i - 1, j)  # lateral +y is the row above
    if not classified.plan.inside(ni, nj):
        return False
    other = classified.cell(ni, nj)
    return other.kind == "parking" and other.type in BAY_TYPES and other.rotation == lay.cell.rotation


def bay_pieces(classified: Classified, lay: BayLayout, width: float) -> list[Piece]:
    lines = lay.lines()
    last = len(lines) - 1
    a0, a1 = lay.across
    h = width / 2
    out = []
    for m, p in enumerate(lines):
        if m == last and _drawn_by_neighbour(classified, lay):
            continue
        # Lines on the cell's edges move inwards so paint never spills into a neighbour (a lane, say).
        p = p + h if m == 0 else p - h if m == last else p
        rect = (p - h, a0, p + h, a1) if lay.along_x else (a0, p - h, a1, p + h)
        out.append((rect, mat.LANE_WHITE, mat.BAY_FLOOR))
    return out


def cell_pieces(classified: Classified, cell: Cell, garage) -> list[Piece]:
    width = float(garage.marking_width)
    if cell.driveable:
        return lane_pieces(classified, cell, width)
    lay = layout(classified, cell, float(garage.bay_width))
    return bay_pieces(classified, lay, width) if lay is not None else []


def build_markings(classified: Classified, garage) -> list[Entity]:
    wear = float(garage.marking_wear)
    if not 0.0 <= wear <= 1.0:
        raise GarageError(f"marking_wear = {wear:g} is outside 0-1", "garage.marking_wear")
    if wear >= 1.0:
        return []  # fully worn paint has the floor's colour: nothing to draw
    plan = classified.plan
    faded: dict[tuple[str, str], Material] = {}
    out = []
    for cell in classified.all_cells():
        pieces = cell_pieces(classified, cell, garage)
        if not pieces:
            continue
        xc, yc = plan.cell_center(cell.i, cell.j)
        shapes = []
        for k, ((x0, y0, x1, y1), paint, floor) in enumerate(pieces):
            if unit_hash(cell.i, cell.j, k) < wear / 2:
                continue
            key = (paint.name, floor.name)
            if key not in faded:
                faded[key] = mat.faded(paint, floor, wear)
            shapes.append(Box((x1 - x0, y1 - y0, PAINT_HEIGHT), faded[key],
                              Pose((x0 + x1) / 2 - xc, (y0 + y1) / 2 - yc, PAINT_HEIGHT / 2)))
        if shapes:
            out.append(Entity(f"marking_{cell.i}_{cell.j}", "marking", Pose(xc, yc, 0.0), shapes))
    return out
