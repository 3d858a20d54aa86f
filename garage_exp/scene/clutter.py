"""Clutter and signage (the `clutter` group: none, typical, dense): what makes a garage look used.

Under the ceiling: ducts, sprinkler mains with heads, cable trays, lamp housings, hanging exit and level signs.
On walls and pillars: fire-extinguisher boxes, level signs. On the floor: wheel stops in the bays, bollards at
the entrances, painted arrows and bay numbers.

Everything is static structure (one merged body per material, like walls), so it hides what stands behind it
in the id picture exactly as a pillar does: ground truth's visible fraction counts it as an occluder. Nothing
low stands in a lane (a bollard would block a case's path); what hangs over lanes stays above 2.2 m.
"""

from __future__ import annotations

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.plan.classify import Classified
from garage_exp.scene.bays import bays, pillar_centre
from garage_exp.scene.description import Box, Decal, Entity, Material, Pose, Scene, Texture

LEVELS = ("none", "typical", "dense")
DUCT = Material("duct_galvanised", (0.42, 0.43, 0.45, 1.0), roughness=0.45, metallic=0.6)
PIPE_RED = Material("pipe_red", (0.45, 0.03, 0.02, 1.0), roughness=0.5)
PIPE_GREY = Material("pipe_grey", (0.2, 0.2, 0.21, 1.0), roughness=0.6)
TRAY = Material("cable_tray", (0.3, 0.3, 0.3, 1.0), roughness=0.5, metallic=0.5)
HOUSING = Material("lamp_housing", (0.5, 0.5, 0.5, 1.0), roughness=0.5, metallic=0.3)
WHEEL_STOP = Material("wheel_stop", (0.3, 0.3, 0.29, 1.0), roughness=0.9)
BOLLARD = Material("bollard_yellow", (0.8, 0.5, 0.0, 1.0), roughness=0.5)
EXTINGUISHER = Material("extinguisher_box", (0.5, 0.02, 0.02, 1.0), roughness=0.4)
EXIT_SIGN = Material("exit_sign", (0.0, 0.25, 0.06, 1.0), roughness=0.4, emission=(0.0, 0.6, 0.15))
LEVEL_SIGN = Material("level_sign", (0.02, 0.08, 0.3, 1.0), roughness=0.5)
FLOOR_PAINT = Material("floor_paint_white", (0.7, 0.7, 0.68, 1.0), roughness=0.6)
SIGN_Z = 0.006


def check_clutter(conf) -> None:
    if str(conf.level) not in LEVELS:
        raise GarageError(f"unknown clutter level {conf.level!r} ({' | '.join(LEVELS)})", "clutter.level")


def _sign(base: Material, text: str, seed: int = 0, clear: bool = False) -> Material:
    params = (("clear", 1.0 if clear else 0.0), ("text", text))
    return Material(f"{base.name}_{text}", base.color, base.roughness, base.metallic, base.emission,
                    Texture("sign", seed, 0.0, params))


def _box(name: str, x: float, y: float, size, material: Material, z: float, yaw: float = 0.0) -> Entity:
    return Entity(name, "structure", Pose(x, y, 0.0), [Box(tuple(size), material, Pose(0.0, 0.0, z, yaw))])


def _lane_runs(classified: Classified) -> list[tuple[str, float, float, float]]:
    """Straight runs of driveable cells: (axis, fixed coordinate of the lane's centre, start, end)."""
    plan = classified.plan
    m, n = plan.shape
    out = []
    for i in range(m):
        j = 0
        while j < n:
            if plan.is_driveable(i, j):
                k = j
                while k + 1 < n and plan.is_driveable(i, k + 1):
                    k += 1
                if k - j >= 2:
                    y = plan.cell_center(i, j)[1]
                    out.append(("x", y, float(plan.x_edges[j]), float(plan.x_edges[k + 1])))
                j = k + 1
            else:
                j += 1
    for j in range(n):
        i = 0
        while i < m:
            if plan.is_driveable(i, j):
                k = i
                while k + 1 < m and plan.is_driveable(k + 1, j):
                    k += 1
                if k - i >= 2:
                    x = plan.cell_center(i, j)[0]
                    out.append(("y", x, float(plan.y_edges[k + 1]), float(plan.y_edges[i])))
                i = k + 1
            else:
                i += 1
    return out


def overhead(classified: Classified, garage, dense: bool) -> list[Entity]:
    """Ducts, sprinkler mains and heads, cable trays along the lanes, off the lamps' centre line."""
    ceiling = float(garage.ceiling_height)
    out = []
    for k, (axis, at, a, b) in enumerate(_lane_runs(classified)):
        length, mid = b - a, (a + b) / 2

        def along(name, off, size_across, height, z, material):
            size = (length, size_across, height) if axis == "x" else (size_across, length, height)
            x, y = (mid, at + off) if axis == "x" else (at + off, mid)
            out.append(_box(f"clutter_{name}_{k}", x, y, size, material, z))

        along("duct", 1.6, 0.5, 0.3, ceiling - 0.18, DUCT)
        along("main", -1.2, 0.1, 0.1, ceiling - 0.12, PIPE_RED)
        along("tray", -0.7, 0.3, 0.06, ceiling - 0.3, TRAY)
        if dense:
            along("pipe", 0.6, 0.15, 0.15, ceiling - 0.45, PIPE_GREY)
        for h, s in enumerate(np.arange(a + 1.5, b - 0.5, 3.0)):
            x, y = (s, at - 1.2) if axis == "x" else (at - 1.2, s)
            out.append(_box(f"clutter_sprinkler_{k}_{h}", x, y, (0.06, 0.06, 0.12), PIPE_GREY, ceiling - 0.2))
    return out


def lamp_housings(scene: Scene) -> None:
    """Each lamp panel gets a metal housing above it: a fixture, not a glowing plank."""
    for e in scene.by_role("lamp"):
        panel = e.shapes[0]
        sx, sy, sz = panel.size
        e.shapes = [*e.shapes, Box((sx + 0.08, sy + 0.08, 0.05), HOUSING,
                                   Pose(0.0, 0.0, panel.offset.z + sz / 2 + 0.02))]


def floor_marks(classified: Classified, garage, seed: int) -> list[Entity]:
    """Painted arrows on lane runs and a number at the lane end of each bay."""
    out = []
    for k, (axis, at, a, b) in enumerate(_lane_runs(classified)):
        for h, s in enumerate(np.arange(a + 4.0, b - 3.0, 12.0)):
            x, y = (s, at - 0.8) if axis == "x" else (at + 0.8, s)
            yaw = 0.0 if axis == "x" else 90.0
            arrow = Material("floor_arrow", FLOOR_PAINT.color, 0.6, texture=Texture("arrow", seed + h, 0.0,
                                                                                     (("wear", 0.3),)))
            out.append(Entity(f"clutter_arrow_{k}_{h}", "marking", Pose(x, y, 0.0),
                              [Decal((2.2, 1.0), arrow, Pose(0.0, 0.0, SIGN_Z, yaw))]))
    for n, bay in enumerate(bays(classified, garage)):
        # near the lane end of the bay, reading from the lane
        dx, dy = np.cos(np.radians(bay.yaw)), np.sin(np.radians(bay.yaw))
        x, y = bay.x + dx * (bay.depth / 2 - 0.6), bay.y + dy * (bay.depth / 2 - 0.6)
        number = _sign(FLOOR_PAINT, f"{n + 1:03d}", clear=True)
        out.append(Entity(f"clutter_bay_number_{n}", "marking", Pose(x, y, 0.0),
                          [Decal((0.9, 0.45), number, Pose(0.0, 0.0, SIGN_Z, bay.yaw + 90.0))]))
    return out


def wheel_stops(classified: Classified, garage) -> list[Entity]:
    """A low concrete block across the back of each bay."""
    out = []
    for n, bay in enumerate(bays(classified, garage)):
        dx, dy = np.cos(np.radians(bay.yaw)), np.sin(np.radians(bay.yaw))
        x, y = bay.x - dx * (bay.depth / 2 - 0.75), bay.y - dy * (bay.depth / 2 - 0.75)
        width = min(1.8, bay.width - 0.5)
        if width > 0.5:
            out.append(_box(f"clutter_wheel_stop_{n}", x, y, (0.15, width, 0.12), WHEEL_STOP, 0.06, bay.yaw))
    return out


def wall_things(scene: Scene, classified: Classified, garage, dense: bool) -> list[Entity]:
    """Extinguisher boxes on the walls' inner faces every ~15 m, a level sign on pillars; bollards at entrances."""
    x0, y0, x1, y1 = scene.bounds
    out = []
    spacing = 8.0 if dense else 15.0
    for e in scene.entities:
        if not e.name.startswith("wall_"):
            continue
        sx, sy = e.shapes[0].size[:2]
        if sx >= sy:
            y = y1 - 0.12 if e.pose.y > (y0 + y1) / 2 else y0 + 0.12
            for k, x in enumerate(np.arange(max(e.pose.x - sx / 2, x0) + spacing / 2, min(e.pose.x + sx / 2, x1), spacing)):
                out.append(_box(f"clutter_extinguisher_{e.name}_{k}", x, y, (0.35, 0.2, 0.55), EXTINGUISHER, 1.2))
        else:
            x = x1 - 0.12 if e.pose.x > (x0 + x1) / 2 else x0 + 0.12
            for k, y in enumerate(np.arange(max(e.pose.y - sy / 2, y0) + spacing / 2, min(e.pose.y + sy / 2, y1), spacing)):
                out.append(_box(f"clutter_extinguisher_{e.name}_{k}", x, y, (0.2, 0.35, 0.55), EXTINGUISHER, 1.2))
    size = float(garage.pillar_size)
    every = 2 if dense else 4
    for n, p in enumerate(classified.pillars):
        if n % every:
            continue
        cx, cy = pillar_centre(classified.plan, p, size)
        sign = _sign(LEVEL_SIGN, "B2")
        out.append(Entity(f"clutter_level_sign_{n}", "structure", Pose(cx, cy, 0.0), [
            Box((size + 0.02, size + 0.02, 0.3), sign, Pose(0.0, 0.0, 1.9))]))
    plan = classified.plan
    for cell in classified.of_type("entrance", "exit"):
        cx, cy = plan.cell_center(cell.i, cell.j)
        rx0, ry0, rx1, ry1 = plan.cell_rect(cell.i, cell.j)
        across_x = any(d in ("N", "S") for d in cell.lanes)
        for side, pos in enumerate(((rx0 + 0.25, cy), (rx1 - 0.25, cy)) if across_x else ((cx, ry0 + 0.25), (cx, ry1 - 0.25))):
            out.append(_box(f"clutter_bollard_{cell.i}_{cell.j}_{side}", *pos, (0.16, 0.16, 0.9), BOLLARD, 0.45))
        sign = _sign(EXIT_SIGN, "EXIT" if cell.kind == "exit" else "IN")
        out.append(Entity(f"clutter_exit_sign_{cell.i}_{cell.j}", "structure", Pose(cx, cy, 0.0), [
            Box((0.08, 0.9, 0.3) if across_x else (0.9, 0.08, 0.3), sign,
                Pose(0.0, 0.0, float(garage.ceiling_height) - 0.4))]))
    return out


def add_clutter(scene: Scene, classified: Classified, garage, level: str, seed: int) -> None:
    if level == "none":
        return
    dense = level == "dense"
    lamp_housings(scene)
    scene.entities.extend(overhead(classified, garage, dense))
    scene.entities.extend(floor_marks(classified, garage, seed))
    scene.entities.extend(wheel_stops(classified, garage))
    scene.entities.extend(wall_things(scene, classified, garage, dense))
