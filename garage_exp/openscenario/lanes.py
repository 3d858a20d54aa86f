"""The plan's driving lanes as straight roads and junctions (what garage.xodr holds), and where on them an
actor stands: the ego's declared lane (`ego_lane`) and any reference point's lane (`lane_of`).

One road per maximal straight run of driveable cells along a row or a column between junction cells, through the
cells' centres from edge to edge; each corner, T-junction and crossroads cell is a junction whose one-way
connecting roads (straight across it, and turns) link the roads that end at its edges."""

from __future__ import annotations

import math
from dataclasses import dataclass

from garage_exp.openscenario.model import Track, reference
from garage_exp.plan.model import OPPOSITE, YAW
from garage_exp.scene.description import Pose


@dataclass
class Run:
    """A maximal straight run of driveable cells between junction cells (one OpenDRIVE road), or the straight way
    through one junction cell (a connecting road of that junction: `junction` > 0)."""

    start: tuple[float, float]
    heading: float  # radians: 0 along a row (E), pi/2 up a column (N)
    length: float
    width: float  # across: the cells' depth (a row's R or a column's C)
    cells: list[tuple[int, int]]  # in the order the road runs
    sides: tuple[float, float]  # the depth of the row or column on its left and on its right (0: none)
    junction: int = 0  # the junction (1, 2, ...) whose connecting road it is; 0: an ordinary road
    side: int = 0  # a connecting road's lanes: -1 the right ones only, 1 the left ones only (one way); 0 both

    def has(self, lane: int) -> bool:
        """Whether the road has lanes on lane id `lane`'s side."""
        return self.side == 0 or (lane > 0) == (self.side > 0)

    def st(self, x: float, y: float) -> tuple[float, float]:
        """(s, t) of a world point on this road's reference line."""
        c, n = math.cos(self.heading), math.sin(self.heading)
        return (x - self.start[0]) * c + (y - self.start[1]) * n, -(x - self.start[0]) * n + (y - self.start[1]) * c


JUNCTION_TYPES = ("corner", "t_junction", "crossroads")


def junction_cells(classified) -> dict[tuple[int, int], int]:
    """The driveable cells where lanes meet (corners, T-junctions, crossroads; plan/classify.py) and each one's
    junction id (1, 2, ... in row-major order)."""
    cells = [(c.i, c.j) for c in classified.all_cells() if c.driveable and c.type in JUNCTION_TYPES]
    return {cell: k for k, cell in enumerate(cells, start=1)}


def lane_runs(classified) -> list[Run]:
    """The straight roads, their index + 1 their road id: maximal straight runs of driveable cells along rows
    (heading E) and columns (heading N) cut at junction cells, then the straight ways across each junction cell
    along a row and a column (its connecting roads, heading E or N as the roads they join, one way each: a pair per
    axis, one with the right lanes and one with the left; across a dead end too, so that whoever stands in a
    corner is on a lane)."""
    plan = classified.plan
    m, n = plan.shape
    junctions = junction_cells(classified)
    runs = []

    def ordinary(cell) -> bool:
        return cell.driveable and (cell.i, cell.j) not in junctions

    def connected(a, b, d) -> bool:
        return ordinary(a) and ordinary(b) and d in a.lanes

    def row(i, j, k, junction=0, side=0) -> Run:
        y = plan.cell_center(i, j)[1]
        sides = (float(plan.R[i - 1]) if i > 0 else 0.0, float(plan.R[i + 1]) if i + 1 < m else 0.0)
        return Run((float(plan.x_edges[j]), y), 0.0, float(plan.x_edges[k + 1] - plan.x_edges[j]),
                   float(plan.R[i]), [(i, c) for c in range(j, k + 1)], sides, junction, side)

    def column(j, i, k, junction=0, side=0) -> Run:  # from row i (the bottom) up to row k
        x = plan.cell_center(i, j)[0]
        sides = (float(plan.C[j - 1]) if j > 0 else 0.0, float(plan.C[j + 1]) if j + 1 < n else 0.0)
        return Run((x, float(plan.y_edges[i + 1])), math.pi / 2, float(plan.y_edges[k] - plan.y_edges[i + 1]),
                   float(plan.C[j]), [(r, j) for r in range(i, k - 1, -1)], sides, junction, side)

    for i in range(m):
        j = 0
        while j < n:
            cell = classified.cell(i, j)
            if not (ordinary(cell) and ({"E", "W"} & set(cell.lanes))):
                j += 1
                continue
            k = j
            while k + 1 < n and connected(classified.cell(i, k), classified.cell(i, k + 1), "E"):
                k += 1
            runs.append(row(i, j, k))
            j = k + 1
    for j in range(n):
        i = m - 1
        while i >= 0:  # from the bottom row up: heading N
            cell = classified.cell(i, j)
            if not (ordinary(cell) and ({"N", "S"} & set(cell.lanes))):
                i -= 1
                continue
            k = i
            while k - 1 >= 0 and connected(classified.cell(k, j), classified.cell(k - 1, j), "N"):
                k -= 1
            runs.append(column(j, i, k))
            i = k - 1
    for (i, j), junction in junctions.items():
        lanes = set(classified.cell(i, j).lanes)
        for side in (-1, 1):  # one way each: the right lanes' traffic and the left lanes'
            if {"E", "W"} & lanes:  # through the cell, or from a dead end (a corner's, a T's stem axis) to its arm
                runs.append(row(i, j, j, junction, side))
            if {"N", "S"} & lanes:
                runs.append(column(j, i, i, junction, side))
    return runs


def side_types(classified, run: Run) -> list[tuple[float, str, str]]:
    """Where along the road the cells beside it change: (s, left type, right type), OpenDRIVE lane types of the
    outer lanes (parking beside bays and free space, none beside walls, obstacles and other lanes)."""
    plan = classified.plan
    m, n = plan.shape
    di, dj = (-1, 0) if run.heading == 0.0 else (0, -1)  # the left neighbour: N of a row, W of a column

    def kind(i, j) -> str:
        if not (0 <= i < m and 0 <= j < n):
            return "none"
        cell = classified.cell(i, j)
        return "parking" if cell.value == 0 else "none"

    out, s = [], 0.0
    for i, j in run.cells:
        types = (kind(i + di, j + dj), kind(i - di, j - dj))
        if not out or out[-1][1:] != types:
            out.append((s, *types))
        s += float(plan.C[j]) if run.heading == 0.0 else float(plan.R[i])
    return out


def ends(run: Run) -> tuple[tuple[int, int], str, tuple[int, int], str]:
    """The cells before a road's start and after its end, and the direction from each back to the road."""
    (i0, j0), (i1, j1) = run.cells[0], run.cells[-1]
    if run.heading == 0.0:
        return (i0, j0 - 1), "E", (i1, j1 + 1), "W"
    return (i0 + 1, j0), "N", (i1 - 1, j1), "S"


def arms(runs: list[Run], junctions: dict) -> dict[tuple[tuple[int, int], str], tuple[int, str]]:
    """(junction cell, direction) -> (road id, the road's contact point there: start or end) of each ordinary road
    that ends at a junction cell."""
    out = {}
    for k, run in enumerate(runs, start=1):
        if run.junction:
            continue
        before, back, after, ahead = ends(run)
        if before in junctions:
            out[before, back] = (k, "start")
        if after in junctions:
            out[after, ahead] = (k, "end")
    return out


@dataclass
class Turn:
    """A connecting road that turns through a junction cell from its arm `arms[0]` to `arms[1]`: a straight piece
    and a quarter circle (or the other way round) from one edge's centre to the other's (cells need not be
    square), its lanes widening from the one road's half width to the other's."""

    cell: tuple[int, int]
    arms: tuple[str, str]
    start: tuple[float, float]
    heading: float
    pieces: list[tuple[str, float, float]]  # ("line", length, 0) | ("arc", curvature, angle)
    widths: tuple[float, float]
    side: int  # its one lane: -1 the right, 1 the left

    @property
    def length(self) -> float:
        return sum(a if kind == "line" else b / abs(a) for kind, a, b in self.pieces)


def turns(classified) -> list[Turn]:
    """The turning connecting roads: a pair (one way each) per pair of perpendicular arms of each junction cell."""
    plan = classified.plan
    out = []
    for (i, j) in junction_cells(classified):
        x0, y0, x1, y1 = plan.cell_rect(i, j)
        xc, yc = plan.cell_center(i, j)
        edge = {"W": (x0, yc), "E": (x1, yc), "S": (xc, y0), "N": (xc, y1)}
        width = {d: float(plan.R[i]) if d in "EW" else float(plan.C[j]) for d in "NESW"}
        lanes = [d for d in "NESW" if d in classified.cell(i, j).lanes]
        for a, d1 in enumerate(lanes):
            for d2 in lanes[a + 1:]:
                if OPPOSITE[d1] == d2:
                    continue
                (px, py), (qx, qy) = edge[d1], edge[d2]
                h0 = math.radians(YAW[OPPOSITE[d1]])
                ahead = (qx - px) * math.cos(h0) + (qy - py) * math.sin(h0)
                side = -(qx - px) * math.sin(h0) + (qy - py) * math.cos(h0)
                r = min(ahead, abs(side))
                pieces = [("line", ahead - r, 0.0)] if ahead - r > 1e-9 else []
                pieces.append(("arc", math.copysign(1.0 / r, side), math.pi / 2))
                if abs(side) - r > 1e-9:
                    pieces.append(("line", abs(side) - r, 0.0))
                out += [Turn((i, j), (d1, d2), (px, py), h0, pieces, (width[d1], width[d2]), side) for side in (-1, 1)]
    return out


@dataclass
class EgoLane:
    """Where a driving ego is on the roads: the road (lane_runs' index + 1), the lane it drives in, the s of its
    reference point at its start and end, its offset from the lane's centre, and the traffic rule that makes that
    lane's driving direction its direction of travel (the side of the centre line it keeps to); `road_end`: the road
    it ends on (through junctions: the straight roads it drives are collinear, its lane id the same on each)."""

    road: int
    lane: int
    s0: float
    s1: float
    offset: float
    rule: str
    road_end: int = 0  # 0: `road`
    # where its route begins when it starts on a connecting road and ends beyond it: the next road's (id, s) where
    # it enters it (a route from a connecting road out of a dead end, which no road enters, is "not valid" in esmini)
    entry: tuple[int, float] | None = None

    @property
    def last(self) -> int:
        return self.road_end or self.road


def ego_lane(runs: list, track: Track) -> EgoLane | None:
    """The lane an ego keeps to, from where it stands and where it travels (standing: where it faces); None when
    it is not on the driving lanes of straight roads along one line (it then goes by world positions). An ego on
    the centre line (t = 0) is in the lane on its right under right-hand traffic, at that lane's left edge:
    declared, not left to rounding."""
    a = reference(track.start, track.entity)
    b = reference(track.end, track.entity) if track.end is not None else a
    travel = math.atan2(b.y - a.y, b.x - a.x) if track.end is not None else math.radians(track.start.yaw)

    def holding(p) -> list[tuple[int, float, float]]:
        out = []
        for k, run in enumerate(runs, start=1):
            if abs(math.sin(run.heading - travel)) > 1e-6:
                continue
            s, t = run.st(p.x, p.y)
            if -1e-6 <= s <= run.length + 1e-6 and abs(t) <= run.width / 2 + 1e-6:
                out.append((k, s, t))
        return out

    for k, s0, t0 in holding(a):
        run = runs[k - 1]
        along = 1 if math.cos(run.heading - travel) > 0 else -1  # travels towards +s or -s
        left = t0 * along > 1e-6
        lane = along if left else -along  # RHT: +s traffic in the right lanes (negative ids); LHT the left
        ends = [(e, s1) for e, s1, t1 in holding(b) if runs[e - 1].heading == run.heading
                and abs(t0 - t1) <= 1e-6 and runs[e - 1].has(lane)]
        ends.sort(key=lambda end: end[0] != k)  # its own road first
        if not run.has(lane) or not ends:
            continue
        end, s1 = ends[0]
        centre = math.copysign(run.width / 4, lane)
        entry = None
        if run.junction and end != k:  # the road it drives onto next, where it enters it
            c, n = math.cos(run.heading), math.sin(run.heading)
            s_out = run.length + 1e-3 if along > 0 else -1e-3
            x, y = run.start[0] + s_out * c - t0 * n, run.start[1] + s_out * n + t0 * c
            following = [(e, s) for e, s, _ in holding(Pose(x, y, 0.0, 0.0))
                         if e != k and runs[e - 1].heading == run.heading and runs[e - 1].has(lane)]
            if following:
                entry = (following[0][0], 0.0 if along > 0 else round(runs[following[0][0] - 1].length, 6))
        return EgoLane(k, lane, round(s0, 6), round(s1, 6), round(t0 - centre, 6), "LHT" if left else "RHT",
                       0 if end == k else end, entry)
    return None


def lane_of(runs: list, pose: Pose) -> tuple[int, int, float, float] | None:
    """(road, lane, s, offset from the lane's centre) of a reference point on the roads: in a driving lane where
    one holds it, else in an outer lane (a bay, the space beside the lane); None off every road."""
    found = None
    for k, run in enumerate(runs, start=1):
        s, t = run.st(pose.x, pose.y)
        if not -1e-6 <= s <= run.length + 1e-6:
            continue
        half = run.width / 2
        side = run.sides[0] if t > 0 else run.sides[1]
        lane = 1 if t > 1e-9 else -1
        if not run.has(lane):  # a one-way connecting road without lanes on this side
            continue
        if abs(t) <= half + 1e-9:
            return k, lane, round(s, 6), round(t - math.copysign(half / 2, lane), 6)
        if found is None and side > 0 and abs(t) <= half + side:
            lane = 2 if t > 0 else -2
            found = k, lane, round(s, 6), round(t - math.copysign(half + side / 2, t), 6)
    return found
