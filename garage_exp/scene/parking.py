"""Parked cars filling a fraction of the free bays (the `palette.parked_occupancy` factor), seeded."""

from __future__ import annotations

import numpy as np

from garage_exp.core.errors import check_range
from garage_exp.scene.bays import Rect, bays, overlap
from garage_exp.scene.description import Box, Entity, Mesh, Pose, Scene


def pillar_footprints(scene: Scene) -> list[Rect]:
    """Pillars as they stand in the scene, after any factor resized them."""
    out = []
    for e in scene.entities:
        if e.name.startswith("pillar_"):
            half = max(s.size[0] for s in e.shapes if isinstance(s, Box)) / 2
            out.append((e.pose.x - half, e.pose.y - half, e.pose.x + half, e.pose.y + half))
    return out


def car_footprint(x: float, y: float, yaw: float, length: float, width: float) -> Rect:
    along_x = round(yaw) % 180 == 0
    hx, hy = (length / 2, width / 2) if along_x else (width / 2, length / 2)
    return (x - hx, y - hy, x + hx, y + hy)


def check_palette(palette) -> None:
    check_range(palette.parked_occupancy, 0.0, 1.0, "palette.parked_occupancy")


def park_vehicles(classified, garage, palette, library, rng: np.random.Generator, scene: Scene, exclude=()
                  ) -> list[Entity]:
    """Cars in round(occupancy * free bays) bays chosen at random, each aligned to its bay (nose to the lane)
    and picked from `palette.parked_classes` among the models that fit the bay, the ceiling and clear the
    scene's pillars; a bay nothing fits stays empty."""
    occupancy = float(palette.parked_occupancy)
    excluded = set(map(tuple, exclude))
    free = [b for b in bays(classified, garage) if (b.i, b.j, b.index) not in excluded]
    count = int(round(occupancy * len(free)))
    if count == 0:
        return []
    chosen = sorted(rng.choice(len(free), size=count, replace=False).tolist())
    allowed = set(palette.models) if palette.models else None
    pillars = pillar_footprints(scene)
    longest = max((m.length for m in library.models), default=0.0)
    widest = max((m.width for m in library.models), default=0.0)
    out = []
    for n, k in enumerate(chosen):
        bay = free[k]
        # Only the pillars the bay's largest car footprint touches can touch any car's: every model's footprint
        # at the bay lies inside it (same centre and axis). A generated garage has hundreds of pillars, and
        # testing each against each model of each bay took about 0.5 s a scene.
        reach = car_footprint(bay.x, bay.y, bay.yaw, longest, widest)
        near = [p for p in pillars if overlap(reach, p) > 0]
        candidates = [m for m in library.models
                      if m.size_class in palette.parked_classes and m.height + 0.1 < garage.ceiling_height
                      and m.length <= bay.depth and m.width <= bay.width + 0.15  # widths include mirrors
                      and (allowed is None or m.name in allowed)
                      and not any(overlap(car_footprint(bay.x, bay.y, bay.yaw, m.length, m.width), p) > 0
                                  for p in near)]
        if not candidates:
            continue
        model = candidates[int(rng.integers(len(candidates)))]
        out.append(Entity(name=f"parked_{n}", role="parked", pose=Pose(bay.x, bay.y, 0.0, bay.yaw),
                          shapes=[Mesh(model.glb)], model=model.name, size_class=model.size_class,
                          extent=(model.length, model.width, model.height), static=True))
    return out
