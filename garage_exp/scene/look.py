"""The `real` look, as scene-description changes every renderer draws: procedural materials (the `materials`
group: clean, worn, wet, random) and contact shadows under vehicles, people, pillars and walls.

Contact shadows are baked decals, not shadow maps: measured on lavapipe, SAPIEN's shadow maps cost 3x a frame
and draw hard shadows of the nearest three lamps only, while the darkening that tells the eye (and a detector)
that a car stands on the floor is the soft one right under it, which an alpha-blended decal gives for the cost
of a quad. They move with their actor and carry no id of its (render/sapien_builder.py), so ground truth is
unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from garage_exp.core.errors import GarageError, check_range
from garage_exp.scene import materials as mat
from garage_exp.scene.lamps import check_light
from garage_exp.scene.description import Box, Decal, Entity, Material, Pose, Scene, Texture

LEVELS = ("none", "clean", "worn", "wet", "random")
SHADOW_Z = 0.008  # above the paint (PAINT_HEIGHT 0.005), below anything standing on the floor
SHADOW = Material("contact_shadow", (0.0, 0.0, 0.0, 1.0), roughness=1.0)
VEHICLE_MARGIN = (0.35, 0.3)  # metres the shadow reaches past a car's footprint, ahead/behind and to the sides
PERSON_SHADOW = 0.9  # diameter (m)
PILLAR_MARGIN = 0.35
WALL_SHADOW = 0.6  # depth (m) of the darkening along a wall's foot
# Lanes in the real look: grey-green epoxy coating, as most underground garages have, not the flat look's
# near-black asphalt (on which neither a black car nor a shadow stands out).
EPOXY = Material(mat.ASPHALT.name, (0.11, 0.125, 0.115, 1.0), roughness=0.55)
SPECULAR = 0.5  # every dressed surface is a dielectric (F0 0.04): lamps glint on gloss and mirror in puddles


@dataclass(frozen=True)
class Dress:
    """One draw of a materials level: how dirty, how wet, how worn the paint, and the seed of the marks."""

    grime: float
    wetness: float
    paint_wear: float
    seed: int
    tint: float = 0.0  # wall paint's shift in brightness (random level only)


def dress_of(level: str, seed: int, grime: float | None = None, wetness: float | None = None) -> Dress:
    """The level's values; `random` draws them from the seed (domain randomisation, one draw a replicate)."""
    if level == "clean":
        out = Dress(0.15, 0.0, 0.05, seed)
    elif level == "worn":
        out = Dress(1.0, 0.0, 0.35, seed)
    elif level == "wet":
        out = Dress(0.8, 0.85, 0.3, seed)
    elif level == "random":
        rng = np.random.default_rng([0x7EA1, seed])
        wet = float(rng.uniform(0.3, 1.0)) if rng.random() < 0.4 else 0.0
        out = Dress(float(rng.uniform(0.0, 1.0)), wet, float(rng.uniform(0.0, 0.6)), seed,
                    float(rng.uniform(-0.25, 0.25)))
    else:
        raise GarageError(f"unknown materials level {level!r} ({' | '.join(LEVELS)})", "materials.level")
    return replace(out, grime=out.grime if grime is None else grime,
                   wetness=out.wetness if wetness is None else wetness)


def check_materials(conf) -> None:
    if str(conf.level) not in LEVELS:
        raise GarageError(f"unknown materials level {conf.level!r} ({' | '.join(LEVELS)})", "materials.level")
    for key, value in (("grime", conf.grime), ("wetness", conf.wetness)):
        if value is not None:
            check_range(float(value), 0.0, 1.0, f"materials.{key}", f"{key} = {value}")


def _textured(base: Material, kind: str, dress: Dress, tile: float = 4.0, **params) -> Material:
    """`base` with its picture. Everything a replicate may redraw (seed, grime, wetness, wear, tint) is in the
    Texture, so `redress` can swap pictures on a loaded scene without touching its geometry."""
    return Material(f"{base.name}~{kind}", base.color, base.roughness, base.metallic, base.emission,
                    Texture(kind, dress.seed, tile, _params(kind, dress, params)), specular=SPECULAR)


# The kinds whose pictures read the grime (scene/textures.py). Ceilings and line paint do not: with the grime in
# their parameters, every scenario of a wide space (which draws the grime per scenario) made its two ceiling
# pictures (384 px) again, with the same pixels.
GRIMED = ("concrete", "asphalt", "wall", "stripes")


def _params(kind: str, dress: Dress, extra: dict) -> tuple:
    values = {**extra, "grime": round(dress.grime, 4)} if kind in GRIMED else dict(extra)
    if kind in ("concrete", "asphalt"):
        values["wetness"] = round(dress.wetness, 4)
    if kind == "paint":
        values["wear"] = round(dress.paint_wear, 4)
    if kind == "wall" and dress.tint:
        values["tint"] = round(dress.tint, 4)
    return tuple(sorted(values.items()))


DRESSED = ("concrete", "asphalt", "wall", "stripes", "paint", "ceiling")


def redress(scene: Scene, dress: Dress) -> dict[Material, Material]:
    """Old -> new material for every dressed surface of a built scene, drawn again for `dress` (one replicate's
    draw): the same shapes with other stains, wetness and wear."""
    out = {}
    for entity in scene.entities:
        for shape in entity.shapes:
            tex = shape.material.texture if isinstance(shape, Box) else None
            if tex is None or tex.kind not in DRESSED or shape.material in out:
                continue
            kept = {k: v for k, v in tex.params if k.startswith("floor_")}
            out[shape.material] = replace(shape.material, texture=replace(
                tex, seed=dress.seed, params=_params(tex.kind, dress, kept)))
    return out


def material_map(dress: Dress) -> dict[str, callable]:
    """Flat material name -> its textured version (markings: by name prefix, see `_paint`)."""
    return {
        mat.ASPHALT.name: lambda m: _textured(EPOXY, "asphalt", dress),
        mat.BAY_FLOOR.name: lambda m: _textured(m, "concrete", dress),
        mat.FREE_FLOOR.name: lambda m: _textured(m, "concrete", dress),
        mat.OBSTACLE.name: lambda m: _textured(m, "wall", dress),
        mat.WALL_PAINT.name: lambda m: _textured(m, "wall", dress),
        mat.WALL_BAND.name: lambda m: _textured(m, "wall", dress),
        mat.PILLAR_PAINT.name: lambda m: _textured(m, "wall", dress),
        mat.PILLAR_BAND.name: lambda m: _textured(m, "stripes", dress, tile=1.0),
        mat.CEILING.name: lambda m: _textured(m, "ceiling", dress),
        mat.BEAM.name: lambda m: _textured(m, "ceiling", dress),
    }


def _paint(m: Material, dress: Dress) -> Material:
    floor = mat.ASPHALT if "yellow" in m.name or "asphalt" in m.name else mat.BAY_FLOOR
    return _textured(m, "paint", dress, tile=2.0, **{f"floor_{c}": v for c, v in zip("rgb", floor.color[:3])})


def dress_scene(scene: Scene, dress: Dress) -> None:
    """Every flat structure and marking material replaced by its textured version (actors keep theirs)."""
    table = material_map(dress)
    cache: dict[Material, Material] = {}

    def swap(m: Material) -> Material:
        if m.texture is not None or m.emission != (0.0, 0.0, 0.0):
            return m
        if m not in cache:
            make = table.get(m.name)
            cache[m] = make(m) if make else _paint(m, dress) if m.name.startswith("paint_") else m
        return cache[m]

    for entity in scene.entities:
        if entity.role in ("structure", "marking") or entity.kind == "box":  # a box actor may look like a pillar
            entity.shapes = [replace(s, material=swap(s.material)) if isinstance(s, Box) else s
                             for s in entity.shapes]


def _shadow(size: tuple[float, float], core: tuple[float, float], shape: str = "box",
            strength: float = 0.85) -> Material:
    params = (("core", round(min(core), 4)), ("core_x", round(core[0], 4)), ("core_y", round(core[1], 4)),
              ("shape", shape), ("strength", strength))
    return replace(SHADOW, name=f"contact_shadow_{shape}_{core[0]:.2f}_{core[1]:.2f}",
                   texture=Texture("shadow", 0, 0.0, params))


def actor_shadow(entity: Entity) -> Decal | None:
    """The soft shadow under an actor: its footprint plus a margin, densest under it."""
    if entity.extent is None:
        return None
    length, width = float(entity.extent[0]), float(entity.extent[1])
    if entity.is_person:
        d = PERSON_SHADOW
        return Decal((d, d), _shadow((d, d), (0.35, 0.35), "round", 0.6), Pose(0.0, 0.0, SHADOW_Z))
    size = (length + 2 * VEHICLE_MARGIN[0], width + 2 * VEHICLE_MARGIN[1])
    core = (0.92 * length / size[0], 0.9 * width / size[1])
    return Decal(size, _shadow(size, core), Pose(0.0, 0.0, SHADOW_Z))


def add_actor_shadows(scene: Scene) -> None:
    for entity in scene.actors():
        if any(isinstance(s, Decal) for s in entity.shapes):
            continue
        decal = actor_shadow(entity)
        if decal is not None:
            entity.shapes = [*entity.shapes, decal]


def add_structure_shadows(scene: Scene) -> None:
    """Ambient occlusion where pillars and walls meet the floor, as static decals (role marking)."""
    out = []
    for entity in scene.entities:
        if entity.role != "structure" or not entity.shapes or not isinstance(entity.shapes[0], Box):
            continue
        box = entity.shapes[0]
        sx, sy = box.size[0], box.size[1]
        if entity.name.startswith("pillar_"):
            size = (sx + 2 * PILLAR_MARGIN, sy + 2 * PILLAR_MARGIN)
            core = (sx / size[0], sy / size[1])
            out.append(Entity(f"ao_{entity.name}", "marking", entity.pose,
                              [Decal(size, _shadow(size, core, strength=0.6), Pose(0.0, 0.0, SHADOW_Z))]))
        elif entity.name.startswith("wall_"):
            out.extend(_wall_shadows(entity, scene.bounds, sx, sy))
    scene.entities.extend(out)


def _wall_shadows(entity: Entity, bounds, sx: float, sy: float) -> list[Entity]:
    """A strip along the wall's inner face (walls stand outside the footprint), dark at the wall."""
    x0, y0, x1, y1 = bounds
    cx, cy = entity.pose.x, entity.pose.y
    material = _shadow((1.0, 1.0), (0.0, 0.0), "edge", 0.55)
    half = WALL_SHADOW / 2
    if sx >= sy:  # runs along x: the N or S wall
        yaw, y = (180.0, y1 - half) if cy > (y0 + y1) / 2 else (0.0, y0 + half)
        lo, hi = max(cx - sx / 2, x0), min(cx + sx / 2, x1)
        pose = Pose((lo + hi) / 2, y, 0.0)
    else:
        yaw, x = (90.0, x1 - half) if cx > (x0 + x1) / 2 else (-90.0, x0 + half)
        lo, hi = max(cy - sy / 2, y0), min(cy + sy / 2, y1)
        pose = Pose(x, (lo + hi) / 2, 0.0)
    if hi - lo <= 0.05:
        return []
    return [Entity(f"ao_{entity.name}", "marking", pose,
                   [Decal((hi - lo, WALL_SHADOW), material, Pose(0.0, 0.0, SHADOW_Z, yaw))])]


def dress_for(materials, seed: int, marking_wear: float = 0.0) -> Dress:
    """The `materials` group's draw for a seed (the job's seed plus the replicate), with the line paint worn
    as much again as the `wear` factor says: 1 - (1 - level's wear) x (1 - the factor's)."""
    out = dress_of(str(materials.level), int(seed) + int(materials.seed), materials.grime,
                   materials.wetness)
    return replace(out, paint_wear=1.0 - (1.0 - out.paint_wear) * (1.0 - float(marking_wear)))


def dress(scene: Scene, classified, garage, look, materials, clutter, seed: int, marking_wear: float = 0.0) -> None:
    """The look's changes to a built scene (actors included): clutter, then materials, then contact shadows.
    `flat` with materials and clutter `none` changes nothing."""
    from garage_exp.scene.clutter import add_clutter

    add_clutter(scene, classified, garage, str(clutter.level), int(seed))
    if str(materials.level) != "none":
        dress_scene(scene, dress_for(materials, seed, marking_wear))
    if bool(look.contact_shadows):
        add_structure_shadows(scene)
        add_actor_shadows(scene)
    drop = float(look.fixture_drop)
    if drop:
        scene.lights = [replace(light, position=(light.position[0], light.position[1], light.position[2] - drop))
                        for light in scene.lights]


def check_look(look) -> None:
    check_range(float(look.fixture_drop), 0.0, 1.5, "look.fixture_drop", f"fixture_drop = {look.fixture_drop}")
    if look.blank_light is not None:
        check_light(look.blank_light, "look.blank_light")
