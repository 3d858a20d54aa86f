"""Plan features the cases are built on, found by the plan model so that a case runs on any plan that has
them: the corner nearest the entrance, straight lane runs with bays beside them."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.plan.classify import Cell, Classified, Pillar
from garage_exp.plan.model import DRIVEABLE, ENTRANCE, OPPOSITE, STEPS, YAW, Plan

UNIT = {"E": (1.0, 0.0), "N": (0.0, 1.0), "W": (-1.0, 0.0), "S": (0.0, -1.0)}


def entrance_distance(plan: Plan) -> np.ndarray:
    """Steps from the nearest entrance through driveable cells (inf where not driveable)."""
    dist = np.full(plan.shape, np.inf)
    queue = deque()
    for i, j in zip(*np.nonzero(plan.S == ENTRANCE)):
        dist[i, j] = 0
        queue.append((int(i), int(j)))
    while queue:
        i, j = queue.popleft()
        for _, a, b in plan.neighbours(i, j):
            if int(plan.S[a, b]) in DRIVEABLE and dist[a, b] == np.inf:
                dist[a, b] = dist[i, j] + 1
                queue.append((a, b))
    return dist


def run_length(plan: Plan, i: int, j: int, heading: str) -> float:
    """Driveable length (m) from the centre of cell (i, j) going `heading` before leaving driveable cells."""
    di, dj = STEPS[heading]
    extent = lambda a, b: float(plan.C[b] if heading in "EW" else plan.R[a])  # noqa: E731
    length = extent(i, j) / 2
    a, b = i + di, j + dj
    while plan.is_driveable(a, b):
        length += extent(a, b)
        a, b = a + di, b + dj
    return length


@dataclass(frozen=True)
class Corner:
    cell: Cell
    approach: str  # heading of a car driving into the corner (E: it comes from the west)
    exit: str  # heading after the bend
    pillar: Pillar  # the pillar at the bend's inner corner
    approach_length: float  # driveable metres before the corner cell's centre
    exit_length: float  # driveable metres after it

    @property
    def centre(self):
        return self.cell.i, self.cell.j


def inner_vertex(cell: Cell) -> tuple[int, int]:
    """Grid vertex at the inner corner of a corner lane cell: between its two lane sides."""
    a = cell.i if "N" in cell.lanes else cell.i + 1
    b = cell.j if "W" in cell.lanes else cell.j + 1
    return a, b


def corners(classified: Classified) -> list[Corner]:
    """Corner lane cells with a pillar at their inner corner, nearest the entrance first."""
    plan = classified.plan
    dist = entrance_distance(plan)
    pillars = {(p.a, p.b): p for p in classified.pillars}
    found = []
    for cell in classified.of_type("corner"):
        pillar = pillars.get(inner_vertex(cell))
        if pillar is None:
            continue
        # The car comes from the lane side nearer the entrance.
        come_from = min(cell.lanes, key=lambda d: dist[cell.i + STEPS[d][0], cell.j + STEPS[d][1]])
        approach = OPPOSITE[come_from]
        leave = next(d for d in cell.lanes if d != come_from)
        found.append((dist[cell.i, cell.j], Corner(
            cell, approach, leave, pillar,
            approach_length=run_length(plan, cell.i, cell.j, come_from),
            exit_length=run_length(plan, cell.i, cell.j, leave))))
    found.sort(key=lambda t: (t[0], t[1].cell.i, t[1].cell.j))
    return [c for _, c in found]


def corner_nearest_entrance(classified: Classified) -> Corner:
    found = corners(classified)
    if not found:
        raise GarageError("no corner lane cell with a pillar at its inner corner (case 1 needs one)",
                          classified.plan.source)
    return found[0]


@dataclass(frozen=True)
class StraightRun:
    """Contiguous straight lane cells along one axis."""

    cells: tuple[Cell, ...]  # in driving order
    heading: str  # E or S (driving order), the run's axis
    bay_sides: tuple[str, ...]  # sides (N/S or E/W) with Type3 bays along the whole run or most of it

    @property
    def length(self) -> float:
        return len(self.cells)


def straight_runs(classified: Classified, min_cells: int = 3) -> list[StraightRun]:
    """Maximal runs of straight lane cells with bays on at least one side, longest (then nearest the
    entrance) first."""
    plan = classified.plan
    dist = entrance_distance(plan)
    runs = []
    for heading, axis_yaw in (("E", 0.0), ("S", 90.0)):
        di, dj = STEPS[heading]
        sides = ("N", "S") if heading == "E" else ("W", "E")
        for cell in classified.all_cells():
            if not _straight_along(cell, axis_yaw):
                continue
            prev = (cell.i - di, cell.j - dj)
            if plan.inside(*prev) and _straight_along(classified.cell(*prev), axis_yaw):
                continue  # not the start of a run
            run = [cell]
            a, b = cell.i + di, cell.j + dj
            while plan.inside(a, b) and _straight_along(classified.cell(a, b), axis_yaw):
                run.append(classified.cell(a, b))
                a, b = a + di, b + dj
            if len(run) < min_cells:
                continue
            with_bays = tuple(s for s in sides if _bays_along(classified, run, s) * 2 >= len(run))
            if with_bays:
                runs.append((-len(run), float(min(dist[c.i, c.j] for c in run)),
                             StraightRun(tuple(run), heading, with_bays)))
    runs.sort(key=lambda t: (t[0], t[1]))
    return [r for *_, r in runs]


def _straight_along(cell: Cell, axis_yaw: float) -> bool:
    return cell.kind == "lane" and cell.type == "straight" and len(cell.lanes) == 2 and cell.rotation == axis_yaw


def _bays_along(classified: Classified, run: list[Cell], side: str) -> int:
    di, dj = STEPS[side]
    count = 0
    for c in run:
        a, b = c.i + di, c.j + dj
        if classified.plan.inside(a, b):
            n = classified.cell(a, b)
            if n.kind == "parking" and n.type in ("type1", "type2", "type3") and OPPOSITE[side] in n.lanes:
                count += 1
    return count


def longest_straight_run(classified: Classified, min_cells: int = 3) -> StraightRun:
    runs = straight_runs(classified, min_cells)
    if not runs:
        raise GarageError(f"no straight lane of {min_cells}+ cells with bays beside it (this case needs one)",
                          classified.plan.source)
    return runs[0]


def heading_yaw(heading: str) -> float:
    return YAW[heading]
