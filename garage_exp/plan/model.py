"""The garage plan: structure matrix S with row depths R and column widths C (metres)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

OBSTACLE, PARKING, LANE, ENTRANCE, EXIT = -1, 0, 1, 2, 3
DRIVEABLE = (LANE, ENTRANCE, EXIT)

# Row/column steps of the four neighbours, keyed by compass direction (row 0 is north).
STEPS = {"N": (-1, 0), "E": (0, 1), "S": (1, 0), "W": (0, -1)}
YAW = {"E": 0.0, "N": 90.0, "W": 180.0, "S": 270.0}
OPPOSITE = {"N": "S", "S": "N", "E": "W", "W": "E"}


@dataclass(frozen=True, eq=False)
class Plan:
    """A validated plan. Build it with `garage_exp.plan.load_plan` or `Plan.from_arrays`."""

    name: str
    S: np.ndarray  # int, m x n
    R: np.ndarray  # float, m: depth of each row (along y)
    C: np.ndarray  # float, n: width of each column (along x)
    source: str = "<memory>"
    # Garage values the plan was sized for, as (key, value) pairs (a generated plan's pillar size, bay width and
    # ceiling height; load.PLAN_GARAGE_KEYS): a job hands them on to `garage.*` (run/preflight.py). Most plans: ().
    garage: tuple[tuple[str, float], ...] = ()

    @property
    def shape(self) -> tuple[int, int]:
        return self.S.shape

    @cached_property
    def x_edges(self) -> np.ndarray:
        """n+1 x coordinates of the column boundaries, from 0."""
        return np.concatenate([[0.0], np.cumsum(self.C)])

    @cached_property
    def y_edges(self) -> np.ndarray:
        """m+1 y coordinates of the row boundaries; row 0 is on top (largest y)."""
        return float(np.sum(self.R)) - np.concatenate([[0.0], np.cumsum(self.R)])

    @property
    def size(self) -> tuple[float, float]:
        """Footprint (width along x, depth along y) in metres."""
        return float(self.x_edges[-1]), float(self.y_edges[0])

    def cell_rect(self, i: int, j: int) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of cell (i, j)."""
        return (float(self.x_edges[j]), float(self.y_edges[i + 1]), float(self.x_edges[j + 1]), float(self.y_edges[i]))

    def cell_center(self, i: int, j: int) -> tuple[float, float]:
        x0, y0, x1, y1 = self.cell_rect(i, j)
        return (x0 + x1) / 2, (y0 + y1) / 2

    def vertex(self, a: int, b: int) -> tuple[float, float]:
        """World position of grid vertex (a, b): the corner between rows a-1/a and columns b-1/b."""
        return float(self.x_edges[b]), float(self.y_edges[a])

    def cell_at(self, x: float, y: float) -> tuple[int, int] | None:
        """The cell containing world point (x, y), or None outside the plan."""
        j = int(np.searchsorted(self.x_edges, x, side="right")) - 1
        i = int(np.searchsorted(-self.y_edges, -y, side="right")) - 1
        m, n = self.shape
        return (i, j) if 0 <= i < m and 0 <= j < n else None

    def inside(self, i: int, j: int) -> bool:
        m, n = self.shape
        return 0 <= i < m and 0 <= j < n

    def neighbours(self, i: int, j: int):
        """(direction, i2, j2) for each in-bounds 4-neighbour."""
        for d, (di, dj) in STEPS.items():
            if self.inside(i + di, j + dj):
                yield d, i + di, j + dj

    def is_driveable(self, i: int, j: int) -> bool:
        return self.inside(i, j) and int(self.S[i, j]) in DRIVEABLE
