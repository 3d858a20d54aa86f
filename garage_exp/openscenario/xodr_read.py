"""An OpenDRIVE file's straight roads, for placing OpenSCENARIO lane and road positions: each road of one line
geometry with its first lane section's widths; any other road is refused with its reason."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Road:
    x: float
    y: float
    hdg: float
    length: float
    lanes: dict[int, float]  # lane id -> width (its first section, at s = 0)

    def point(self, s: float, t: float) -> tuple[float, float]:
        c, n = math.cos(self.hdg), math.sin(self.hdg)
        return self.x + s * c - t * n, self.y + s * n + t * c

    def lane_at(self, t: float) -> int | None:
        """The lane whose span holds t (None: off the road)."""
        for sign in (1, -1):
            edge = 0.0
            for k in range(1, len(self.lanes) + 1):
                width = self.lanes.get(sign * k)
                if width is None:
                    break
                if edge <= sign * t <= edge + width:
                    return sign * k
                edge += width
        return None

    def lane_centre(self, lane: int) -> float:
        """t of a lane's centre line (left lanes positive ids, right negative)."""
        sign = 1 if lane > 0 else -1
        inner = sum(self.lanes.get(sign * k, 0.0) for k in range(1, abs(lane)))
        return sign * (inner + self.lanes.get(lane, 0.0) / 2)


def read_roads(xodr: Path) -> tuple[dict[str, Road], dict[str, str]]:
    """The OpenDRIVE file's straight roads by id; and each other road's reason it cannot be placed."""
    from garage_exp.openscenario.asam import parse

    roads, refused = {}, {}
    for road in parse(xodr).getroot().iter("road"):
        rid = road.get("id")
        geometries = road.findall("planView/geometry")
        kinds = {child.tag for g in geometries for child in g}
        if len(geometries) != 1 or kinds != {"line"}:
            refused[rid] = f"its plan view is {', '.join(sorted(kinds)) or 'empty'} ({len(geometries)} pieces), " \
                           "not one straight line"
            continue
        g = geometries[0]
        lanes = {}
        section = road.find("lanes/laneSection")
        for lane in (section.iter("lane") if section is not None else []):
            width = lane.find("width")
            if width is not None and lane.get("id") != "0":
                lanes[int(lane.get("id"))] = float(width.get("a", 0))
        roads[rid] = Road(float(g.get("x")), float(g.get("y")), float(g.get("hdg")), float(g.get("length")), lanes)
    return roads, refused
