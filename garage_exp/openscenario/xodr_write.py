"""The garage as ASAM OpenDRIVE 1.7 (`garage.xodr`), written with `scenariogeneration`: the lanes (lanes.py)
with a driving lane each side of the cells' centre line and an outer lane beyond each, the junctions and their
connecting roads linked lane by lane, and the garage's fixed things (pillars, walls, obstacles, bays) as objects."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from garage_exp.openscenario.lanes import Run, arms, ends, junction_cells, lane_runs, side_types, turns
from garage_exp.plan.model import OPPOSITE


@dataclass
class Thing:
    """A fixed thing of the garage as an OpenDRIVE object: its centre, heading (radians), size, type."""

    kind: str  # OpenDRIVE object type: pole (a pillar), barrier (a wall), building (an obstacle cell), parkingSpace
    name: str
    x: float
    y: float
    hdg: float
    length: float
    width: float
    height: float


def garage_things(classified, pillar_size: float = 0.6, height: float = 2.8, wall: float = 0.25) -> list[Thing]:
    """The pillars, the perimeter walls, the obstacle cells and the bays (parking cells beside a lane) of the
    plan, with their dimensions."""
    from garage_exp.plan.draw import _perimeter_walls

    plan = classified.plan
    out = []
    for k, p in enumerate(classified.pillars):
        x, y = plan.vertex(p.a, p.b)
        out.append(Thing("pole", f"pillar_{k}", x + p.sx * pillar_size / 2, y + p.sy * pillar_size / 2, 0.0,
                         pillar_size, pillar_size, height))
    for k, ((x0, y0), (x1, y1)) in enumerate(_perimeter_walls(classified)):
        out.append(Thing("barrier", f"wall_{k}", (x0 + x1) / 2, (y0 + y1) / 2, math.atan2(y1 - y0, x1 - x0),
                         math.hypot(x1 - x0, y1 - y0), wall, height))
    for cell in classified.all_cells():
        if cell.value == -1 or (cell.value == 0 and cell.lanes):
            x0, y0, x1, y1 = plan.cell_rect(cell.i, cell.j)
            kind, name = ("building", "obstacle") if cell.value == -1 else ("parkingSpace", "bay")
            out.append(Thing(kind, f"{name}_{cell.i}_{cell.j}", (x0 + x1) / 2, (y0 + y1) / 2, 0.0, x1 - x0, y1 - y0,
                             height if cell.value == -1 else 0.0))
    return out


def _add_objects(odr, roads: list, runs: list[Run], things: list[Thing]) -> None:
    """Each thing on the road nearest its centre (s clamped to the road, t across it, heading relative)."""
    import numpy as np
    from scenariogeneration import xodr

    # Every road's distance to a thing at once (a large plan: thousands of things x a hundred roads), with
    # Run.st's operations in its order (math's cos and sin), so the nearest road is the one it picks one by one
    # (argmin: the first of equals, as min does).
    sx, sy = np.array([r.start[0] for r in runs]), np.array([r.start[1] for r in runs])
    c, n = np.array([math.cos(r.heading) for r in runs]), np.array([math.sin(r.heading) for r in runs])
    length = np.array([r.length for r in runs])
    for th in things:
        dx, dy = th.x - sx, th.y - sy
        s, t = dx * c + dy * n, -dx * n + dy * c
        near = int(np.argmin(np.maximum(np.maximum(-s, s - length), 0.0) + np.abs(t)))
        s, t = runs[near].st(th.x, th.y)
        obj = xodr.Object(round(min(max(s, 0.0), runs[near].length), 6), round(t, 6),
                          Type=getattr(xodr.ObjectType, th.kind), subtype=th.name.split("_")[0],
                          name=th.name,
                          hdg=round(th.hdg - runs[near].heading, 9), length=round(th.length, 6),
                          width=round(th.width, 6), height=round(th.height, 6))
        roads[near].add_object(obj)


def _link_connecting(road, lane, side: int, forward: bool, junction, before, after) -> None:
    """A one-way connecting road's links: to the road at its start (`before`: road id, contact point) and at its
    end (`after`), its lane's (id `side`) links to theirs, and the junction's connection from the road its traffic
    comes from (`forward`: its traffic runs along s, from `before`)."""
    from scenariogeneration import xodr

    for link, end, other in (("predecessor", "start", before), ("successor", "end", after)):
        if other is None:
            continue
        rid, contact = other
        getattr(road, f"add_{link}")(xodr.ElementType.road, rid, getattr(xodr.ContactPoint, contact))
        theirs = side if contact != end else -side  # start to end keeps lane ids, start to start flips them
        lane.add_link(link, theirs)
        if forward == (end == "start"):
            connection = xodr.Connection(rid, road.id, getattr(xodr.ContactPoint, end))
            connection.add_lanelink(theirs, side)
            junction.add_connection(connection)


def write_xodr(classified, path: Path, rule: str = "RHT", things: list[Thing] | None = None) -> Path:
    """The plan's driving lanes as OpenDRIVE roads (lane_runs), in the world frame of the plan: a driving lane
    each side of the cells' centre line (half the cell's width), and beyond each an outer lane as deep as the
    neighbouring row or column, of type parking beside bays and free space, none beside walls (so that no bay
    and no one standing in it is off the road). `rule`: the traffic rule the roads declare (RHT or LHT).
    Each junction cell (corner, T-junction, crossroads) is an OpenDRIVE junction: the roads end at its edges and
    link to it, and its connecting roads (straight through it, and turns) link to them, lane by lane."""
    from scenariogeneration import xodr

    odr = xodr.OpenDrive(f"garage {classified.plan.name}", revMinor="7")
    traffic = getattr(xodr.TrafficRule, rule)
    runs, roads = lane_runs(classified), []
    cells = junction_cells(classified)
    touch = arms(runs, cells)
    junctions = {jid: xodr.Junction(f"cell {i} {j}", jid) for (i, j), jid in cells.items()}
    def forward(side: int) -> bool:  # a one-way road's traffic runs along s: RHT's right lanes, LHT's left
        return (side < 0) == (rule == "RHT")

    for k, run in enumerate(runs, start=1):
        planview = xodr.PlanView(run.start[0], run.start[1], run.heading)
        planview.add_geometry(xodr.Line(run.length))
        lanes = xodr.Lanes()
        for s, left_type, right_type in side_types(classified, run):
            section = xodr.LaneSection(s, xodr.Lane(xodr.LaneType.none))
            driving = {}
            for side, add, depth, outer in ((-1, section.add_right_lane, run.sides[1], right_type),
                                            (1, section.add_left_lane, run.sides[0], left_type)):
                if not run.has(side):
                    continue
                driving[side] = xodr.Lane(xodr.LaneType.driving, a=run.width / 2)
                add(driving[side])
                if depth > 0:
                    add(xodr.Lane(getattr(xodr.LaneType, outer), a=depth))
            lanes.add_lanesection(section)
        road = xodr.Road(k, planview, lanes, road_type=run.junction or -1, rule=traffic)
        before, back, after, ahead = ends(run)
        if run.junction:
            cell = run.cells[0]
            _link_connecting(road, driving[run.side], run.side, forward(run.side), junctions[run.junction],
                             touch.get((cell, OPPOSITE[back])), touch.get((cell, OPPOSITE[ahead])))
        else:
            if before in cells:
                road.add_predecessor(xodr.ElementType.junction, cells[before])
            if after in cells:
                road.add_successor(xodr.ElementType.junction, cells[after])
        roads.append(road)
        odr.add_road(road)
    for k, turn in enumerate(turns(classified), start=len(runs) + 1):
        planview = xodr.PlanView(turn.start[0], turn.start[1], turn.heading)
        for kind, a, b in turn.pieces:
            planview.add_geometry(xodr.Line(a) if kind == "line" else xodr.Arc(a, angle=b))
        (w0, w1), length = turn.widths, turn.length
        section = xodr.LaneSection(0, xodr.Lane(xodr.LaneType.none))
        lane = xodr.Lane(xodr.LaneType.driving, a=w0 / 2, b=(w1 - w0) / 2 / length)
        (section.add_right_lane if turn.side < 0 else section.add_left_lane)(lane)
        lanes = xodr.Lanes()
        lanes.add_lanesection(section)
        jid = cells[turn.cell]
        road = xodr.Road(k, planview, lanes, road_type=jid, rule=traffic)
        _link_connecting(road, lane, turn.side, forward(turn.side), junctions[jid],
                         touch.get((turn.cell, turn.arms[0])), touch.get((turn.cell, turn.arms[1])))
        odr.add_road(road)
    for junction in junctions.values():
        odr.add_junction(junction)
    _add_objects(odr, roads, runs, things if things is not None else garage_things(classified))
    odr.adjust_startpoints()  # the lanes' links are set above (adjust_roads_and_lanes would guess them again)
    path.parent.mkdir(parents=True, exist_ok=True)
    odr.write_xml(str(path))
    # the header's bounds: the plan's extent (scenariogeneration writes 0)
    from garage_exp.openscenario.asam import parse

    tree = parse(path)
    width, depth = classified.plan.size
    tree.getroot().find("header").attrib.update(
        {"north": f"{depth:.6f}", "south": "0.0", "east": f"{width:.6f}", "west": "0.0"})
    tree.write(str(path), xml_declaration=True, encoding="utf-8")
    return path
