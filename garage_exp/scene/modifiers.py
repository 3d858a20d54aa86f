"""Scene modifiers: the extension point for new factors.

A factor is a config group whose YAML names a modifier with `_target_` (packaged under `modifiers.<group>`);
the job calls it as `modifier(scene, classified, garage, **params)` after the garage is built. A modifier
changes the scene description in place, so it works for every renderer and for the glTF export.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from garage_exp.core.errors import GarageError
from garage_exp.core.plugins import build, check_target
from garage_exp.scene.description import Box, Scene


def remove_entity(scene: Scene, name: str) -> None:
    before = len(scene.entities)
    scene.entities[:] = [e for e in scene.entities if e.name != name]
    if len(scene.entities) == before:
        raise GarageError(f"no entity named {name!r} in the scene", "occluder")


def _pillar(classified, name: str):
    try:
        _, a, b = name.split("_")
        key = (int(a), int(b))
    except ValueError:
        raise GarageError(f"{name!r} is not a pillar name (pillar_<a>_<b>)", "pillar") from None
    for p in classified.pillars:
        if (p.a, p.b) == key:
            return p
    raise GarageError(f"{name} is not on the plan's pillar grid", "pillar")


def resize_pillar(scene: Scene, name: str, size: float, classified) -> None:
    """Give one pillar a new square section; its shift off the vertex scales with it, so it stays out
    of the lanes."""
    if not 0.05 <= size <= 3.0:
        raise GarageError(f"pillar size {size} m is outside 0.05-3 m", "pillar size")
    entity = scene.entity(name)
    p = _pillar(classified, name)
    vx, vy = classified.plan.vertex(p.a, p.b)
    entity.pose = replace(entity.pose, x=vx + p.sx * size / 2, y=vy + p.sy * size / 2)
    entity.shapes = [replace(s, size=(size, size, s.size[2]), offset=replace(s.offset, x=0.0, y=0.0))
                     if isinstance(s, Box) else s for s in entity.shapes]


def pillar_size(scene: Scene, classified, garage, size: float = 0.6) -> None:
    """Factor `pillar`: every pillar gets a `size` x `size` section (metres)."""
    for entity in [e for e in scene.entities if e.name.startswith("pillar_")]:
        resize_pillar(scene, entity.name, size, classified)


def marking_wear(scene: Scene, classified, garage, wear: float = 0.0) -> None:
    """Factor `wear`: lane and bay paint faded by `wear` (0 fresh .. 1 gone), dashes lost at random."""
    from garage_exp.scene.markings import build_markings

    if not 0.0 <= wear <= 1.0:
        raise GarageError(f"wear {wear} is outside 0-1", "wear")
    if abs(wear - garage.marking_wear) < 1e-12:
        return
    scene.entities[:] = [e for e in scene.entities if e.role != "marking"]
    scene.entities.extend(build_markings(classified, replace_conf(garage, marking_wear=wear)))


def replace_conf(conf, **changes):
    """A copy of a dataclass or config node (or dict) with some fields changed."""
    from garage_exp.core.plain import as_object, frozen

    copy = as_object(conf)
    return frozen({**copy, **changes}) if isinstance(copy, dict) else replace(copy, **changes)


def check_modifiers(modifiers: dict[str, Any]) -> None:
    """The `modifiers` groups name only allowed functions (configs are data, see garage_exp.core.plugins)."""
    for group, spec in (modifiers or {}).items():
        check_target(str((spec or {}).get("_target_") or ""), "a scene modifier", f"modifiers.{group}")


def apply_modifiers(scene: Scene, classified, garage, modifiers: dict[str, Any]) -> None:
    """Call each configured modifier in name order (deterministic)."""
    for group in sorted(modifiers):
        build(modifiers[group], "a scene modifier", f"modifiers.{group}", scene, classified, garage)
