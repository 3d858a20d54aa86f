"""Parking bays: how a bay cell (Type1-3) is divided along its lane edge, and where each bay is.

A bay cell is k = max(1, floor(width along its lane edge / bay_width)) bays side by side, each running the
cell's depth away from the lane. A pillar at one of the cell's corners narrows the bay it stands in, so a car
centred in a `Bay` never stands in a pillar. Also home to the pillar and rectangle geometry the structure,
lamps and markings share, and the beams between pillars.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from garage_exp.core.state import STATE
from garage_exp.plan.classify import Cell, Classified, Pillar
from garage_exp.plan.model import Plan

Rect = tuple[float, float, float, float]  # (xmin, ymin, xmax, ymax)

BAY_TYPES = ("type1", "type2", "type3")
SIDE_OF_YAW = {0.0: "E", 90.0: "N", 180.0: "W", 270.0: "S"}
MIN_BAY_WIDTH = 1.0  # narrower than this after a pillar takes its share, it is no bay at all
EPS = 1e-9
BEAM_DEPTH = 0.25
BEAM_WIDTH = 0.3  # narrower than the slimmest pillar level (0.4 m) so a beam never sticks out of one


@dataclass(frozen=True)
class Bay:
    """One parking bay. yaw points where a parked car's nose points: towards the lane."""

    i: int
    j: int
    index: int  # k-th bay of the cell, counted along +x (lane edge along x) or +y
    x: float
    y: float
    yaw: float
    width: float  # along the lane edge, after pillars
    depth: float  # away from the lane
    type: str  # type1 | type2 | type3

    @property
    def rect(self) -> Rect:
        along_x = self.yaw in (90.0, 270.0)  # facing N/S: the bay's width runs along x
        hx, hy = (self.width / 2, self.depth / 2) if along_x else (self.depth / 2, self.width / 2)
        return (self.x - hx, self.y - hy, self.x + hx, self.y + hy)


@dataclass(frozen=True)
class BayLayout:
    """A bay cell's division: `lateral` is the extent along the lane edge, `across` away from it."""

    cell: Cell
    side: str  # direction of the lane from the cell (N/E/S/W)
    along_x: bool  # the lane edge runs along x (lane to the N or S)
    lateral: tuple[float, float]
    across: tuple[float, float]
    count: int

    def lines(self) -> list[float]:
        """Lateral positions of the k+1 lines that bound the bays (both cell edges included)."""
        lo, hi = self.lateral
        return [lo + m * (hi - lo) / self.count for m in range(self.count + 1)]


def overlap(a: Rect, b: Rect) -> float:
    """Area shared by two rectangles (0 when they only touch)."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return w * h if w > 0 and h > 0 else 0.0


def pillar_centre(plan: Plan, pillar: Pillar, size: float) -> tuple[float, float]:
    x, y = plan.vertex(pillar.a, pillar.b)
    return x + pillar.sx * size / 2, y + pillar.sy * size / 2


def pillar_rect(plan: Plan, pillar: Pillar, size: float) -> Rect:
    x, y = pillar_centre(plan, pillar, size)
    h = size / 2
    return (x - h, y - h, x + h, y + h)


def pillars_by_vertex(classified: Classified) -> dict[tuple[int, int], Pillar]:
    return {(p.a, p.b): p for p in classified.pillars}


def cell_pillars(classified: Classified, i: int, j: int, by_vertex: dict[tuple[int, int], Pillar]) -> list[Pillar]:
    """Pillars at the four corners of cell (i, j): the only ones that can reach into it while pillars are
    smaller than cells (a pillar never leaves the cells around its vertex)."""
    return [p for v in ((i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)) if (p := by_vertex.get(v)) is not None]


def bay_count(width: float, bay_width: float) -> int:
    # The tolerance keeps 7.5 / 2.5 at 3 bays despite floating point.
    return max(1, int(math.floor(width / bay_width + 1e-6)))


def layout(classified: Classified, cell: Cell, bay_width: float) -> BayLayout | None:
    """The division of a Type1-3 cell into bays; None for any other cell."""
    if cell.kind != "parking" or cell.type not in BAY_TYPES:
        return None
    side = SIDE_OF_YAW[cell.rotation % 360.0]
    x0, y0, x1, y1 = classified.plan.cell_rect(cell.i, cell.j)
    along_x = side in ("N", "S")
    lateral, across = ((x0, x1), (y0, y1)) if along_x else ((y0, y1), (x0, x1))
    return BayLayout(cell, side, along_x, lateral, across, bay_count(lateral[1] - lateral[0], bay_width))


def _narrowed(lo: float, hi: float, rect_of, pillars: list[Rect], along_x: bool) -> tuple[float, float]:
    """Move the bay's lateral sides inwards past every pillar that stands in it."""
    for pr in pillars:
        if overlap(rect_of(lo, hi), pr) <= EPS:
            continue
        p_lo, p_hi = (pr[0], pr[2]) if along_x else (pr[1], pr[3])
        if (p_lo + p_hi) / 2 < (lo + hi) / 2:
            lo = max(lo, p_hi)
        else:
            hi = min(hi, p_lo)
    return lo, hi


def cell_bays(classified: Classified, lay: BayLayout, pillar_size: float,
              by_vertex: dict[tuple[int, int], Pillar]) -> list[Bay]:
    plan = classified.plan
    cell = lay.cell
    pillars = [pillar_rect(plan, p, pillar_size) for p in cell_pillars(classified, cell.i, cell.j, by_vertex)]
    a0, a1 = lay.across

    def rect_of(lo: float, hi: float) -> Rect:
        return (lo, a0, hi, a1) if lay.along_x else (a0, lo, a1, hi)

    lines = lay.lines()
    out = []
    for k in range(lay.count):
        lo, hi = _narrowed(lines[k], lines[k + 1], rect_of, pillars, lay.along_x)
        if hi - lo < MIN_BAY_WIDTH:
            continue
        mid, centre = (lo + hi) / 2, (a0 + a1) / 2
        x, y = (mid, centre) if lay.along_x else (centre, mid)
        out.append(Bay(cell.i, cell.j, k, x, y, cell.rotation % 360.0, hi - lo, a1 - a0, cell.type))
    return out


# A scene's build asks for the same plan's bays several times (every straight run's site, the parked cars, the
# floor marks and wheel stops): on a generated garage each time took ~6 ms, ~9 times a scene. Kept by the plan
# (by identity: the classified plan is itself cached per file) and the two sizes, for the last few plans.
_BAYS: dict = STATE.cache("scene.bays.bays", "process")
BAYS_KEPT = 32


def bays(classified: Classified, garage) -> list[Bay]:
    """Every bay of the plan, row by row, then column by column, then along the lane edge."""
    bay_width, pillar_size = float(garage.bay_width), float(garage.pillar_size)
    key = (id(classified), bay_width, pillar_size)
    held = _BAYS.get(key)
    if held is not None and held[0] is classified:
        return list(held[1])
    out = tuple(_all_bays(classified, bay_width, pillar_size))
    if len(_BAYS) >= BAYS_KEPT:
        del _BAYS[next(iter(_BAYS))]  # the oldest
    _BAYS[key] = (classified, out)  # the plan held too: its id is not reused while the entry lives
    return list(out)


def _all_bays(classified: Classified, bay_width: float, pillar_size: float) -> list[Bay]:
    by_vertex = pillars_by_vertex(classified)
    out = []
    for cell in classified.all_cells():
        lay = layout(classified, cell, bay_width)
        if lay is not None:
            out.extend(cell_bays(classified, lay, pillar_size, by_vertex))
    return out


@dataclass(frozen=True)
class Beam:
    name: str
    rect: Rect
    cells: tuple[tuple[int, int], tuple[int, int]]  # the two cells whose shared edge the beam follows


def beams(classified: Classified, garage) -> list[Beam]:
    """Downstand beams from pillar to pillar along cell edges between two non-driveable cells (between bays),
    where the two pillars line up. Beams never cross a lane, so the headroom over lanes stays the ceiling's."""
    plan = classified.plan
    size = float(garage.pillar_size)
    by_vertex = pillars_by_vertex(classified)
    h = BEAM_WIDTH / 2
    out = []
    for (a, b), p in by_vertex.items():  # classify lists pillars row by row already
        x, y = pillar_centre(plan, p, size)
        # Eastward along row line a: the edge between cells (a-1, b) and (a, b).
        q = by_vertex.get((a, b + 1))
        cells = ((a - 1, b), (a, b))
        if q is not None and q.sy == p.sy and not any(plan.is_driveable(*c) for c in cells):
            x2, _ = pillar_centre(plan, q, size)
            out.append(Beam(f"beam_{a}_{b}_e", (x, y - h, x2, y + h), cells))
        # Southward along column line b: the edge between cells (a, b-1) and (a, b).
        q = by_vertex.get((a + 1, b))
        cells = ((a, b - 1), (a, b))
        if q is not None and q.sx == p.sx and not any(plan.is_driveable(*c) for c in cells):
            _, y2 = pillar_centre(plan, q, size)
            out.append(Beam(f"beam_{a}_{b}_s", (x - h, y2, x + h, y), cells))
    return out
