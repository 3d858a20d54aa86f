"""What an actor is: a vehicle (by model, or size class, colour and body), a pedestrian (age group, height,
build, pose, clothing) or a static occluder (a box: a barrier, a crate, a low wall), as a scene entity."""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field, replace

from garage_exp.assets.vehicles import COLOURS, SIZE_CLASSES
from garage_exp.assets.vehicles import KINDS as VEHICLE_KINDS
from garage_exp.core.errors import GarageError
from garage_exp.scenario.place import site_bay
from garage_exp.scene.description import Box, Entity, Material, Mesh, Pose

KINDS = ("vehicle", "person", "box")
ROLES = ("ego", "target", "occluder", "parked", "moving")
BOX_COLOURS = {"grey": (0.35, 0.35, 0.34), "yellow": (0.85, 0.6, 0.05), "red": (0.6, 0.08, 0.06),
               "white": (0.75, 0.75, 0.73), "blue": (0.1, 0.2, 0.55), "orange": (0.9, 0.35, 0.05)}


STATURE_STEP = 0.05  # m: a person's height drawn by `stature` is rounded to this (height_of)
# The people an actor's `type` names: (age group, pose; None keeps the actor's own pose).
PEOPLE_TYPES = {"child": ("child", None), "adult": ("adult", None), "crouching": ("adult", "crouching")}


def resolve_type(actor, where: str = "case.actors"):
    """The actor with its one-key `type` spelled out: a person's kind, age group (and pose), a pillar (a box
    painted as the garage's pillars), or a vehicle's model (any name of the library; an unknown one is refused
    where the model is drawn). The one place `type`
    is read: every placement and entity sees the resolved actor."""
    kind = str(actor.type or "")
    if not kind:
        return actor
    if kind in PEOPLE_TYPES:
        age, pose = PEOPLE_TYPES[kind]
        return replace(actor, kind="person", age=age, pose=pose or actor.pose, model="")
    if kind == "pillar":  # a box painted as the garage's pillars (its size: length, width, height)
        return replace(actor, kind="box", colour="pillar", model="")
    if kind in KINDS:
        raise GarageError(f"type {kind!r} is a kind, not a type: give a vehicle model's name, "
                          f"{', '.join(PEOPLE_TYPES)} or pillar", where + ".type")
    return replace(actor, kind="vehicle", model=kind)


def paint_of(actor, where: str = "case.actors") -> tuple[float, float, float] | None:
    """A vehicle's paint as linear RGB from its `hue` (degrees), `saturation` and `lightness` (HLS, sRGB), or
    None when none is set (the model's own paint). The one place the paint keys are read."""
    hls = (actor.hue, actor.lightness, actor.saturation)
    if all(v is None for v in hls):
        return None
    hue, light, sat = (0.0 if actor.hue is None else float(actor.hue),
                       0.5 if actor.lightness is None else float(actor.lightness),
                       0.5 if actor.saturation is None else float(actor.saturation))
    for key, value, hi in (("hue", hue, 360.0), ("lightness", light, 1.0), ("saturation", sat, 1.0)):
        if not 0.0 <= value <= hi:
            raise GarageError(f"{key} {value:g} is outside 0-{hi:g}", f"{where}.{key}")
    srgb = colorsys.hls_to_rgb((hue % 360.0) / 360.0, light, sat)
    return tuple(round(c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4, 5) for c in srgb)


@dataclass
class Made:
    entity: Entity
    extent: tuple[float, float, float]  # length (along its heading), width, height
    bays: list[tuple[int, int, int]] = field(default_factory=list)  # bays it stands in: kept free of parked cars
    source: str = ""  # the scenario's name for it (a palette-coloured actor's copies share one)


def vehicle_entity(name: str, role: str, model, pose: Pose = Pose(), paint=None) -> Entity:
    return Entity(name=name, role=role, pose=pose, shapes=[Mesh(model.glb, paint=paint)], model=model.name,
                  size_class=model.size_class, extent=(model.length, model.width, model.height), static=False,
                  kind="vehicle")


def make(name: str, actor, job, library, site, bays: dict, rng, source: str = "", bay=None) -> Made:
    """The actor's entity. `bay`: the bay it was given (a free bay near the focus), when not named."""
    where = source = source or f"case.actors.{name}"
    if actor.role not in ROLES:
        raise GarageError(f"unknown role {actor.role!r} ({' | '.join(ROLES)})", where + ".role")
    own = [site_bay(site, ref, bays, where).bay for ref in ([actor.bay] if actor.bay != "" else [])
           + list(actor.between)]
    fit = bay or (own[0] if actor.bay != "" else None)
    used = [_bay_key(b) for b in own + ([bay] if bay else [])]
    if actor.kind == "vehicle":
        model = vehicle_model(where, actor, job, library, rng, fit, narrow=bay is not None)
        entity = vehicle_entity(name, actor.role, model, paint=paint_of(actor, where))
    elif actor.kind == "person":
        entity = person_entity(name, actor, where)
    elif actor.kind == "box":
        entity = box_entity(name, actor, where)
    else:
        raise GarageError(f"unknown kind {actor.kind!r} ({' | '.join(KINDS)})", where + ".kind")
    return Made(entity, entity.extent, used, source)


def _bay_key(bay) -> tuple[int, int, int]:
    return (bay.i, bay.j, bay.index)


def vehicle_model(where: str, actor, job, library, rng, bay=None, narrow: bool = False):
    """The named model; else the palette's pinned target of the actor's colour (targets copied per palette
    colour); else a model drawn from the library by size class, colour and body that fits the garage."""
    palette = job.palette
    ceiling = job.garage.ceiling_height - 0.1
    for value, allowed, key in ((actor.colour, COLOURS, "colour"), (actor.size, SIZE_CLASSES, "size"),
                                (actor.body, VEHICLE_KINDS, "body")):
        if value and value not in allowed:
            raise GarageError(f"unknown {key} {value!r} ({', '.join(allowed)})", f"{where}.{key}")
    if actor.model:
        try:
            return library.get(actor.model)
        except GarageError as exc:  # a model named by `type`: said at that key
            if not actor.type:
                raise
            raise GarageError(str(exc)[len(exc.where or "") + 2:] if exc.where else str(exc), f"{where}.type") from None
    if actor.role == "target" and actor.colour in palette.target_colours:
        pinned = dict(palette.target_models or {})
        if palette.target:
            return library.get(palette.target)
        if actor.colour in pinned:
            return library.get(pinned[actor.colour])
        return library.choose(size_class=actor.size or "medium", colour=actor.colour, max_height=ceiling,
                              kind=actor.body or "car", rng=rng)
    fit = dict(size_class=actor.size or None, max_height=ceiling, rng=rng, kind=actor.body or None)
    if bay is not None:
        fit["max_length"] = bay.depth + 0.3
        if narrow:  # beside other cars in neighbouring bays: no wider than the bay
            fit["max_width"] = bay.width - 0.05
    if actor.colour:
        try:
            return library.choose(colour=actor.colour, **fit)
        except GarageError:  # no model of that size in that colour: any colour
            pass
    return library.choose(**fit)


def person_entity(name: str, actor, where: str) -> Entity:
    from garage_exp.assets.people import PeopleLibrary

    try:
        body = PeopleLibrary().body(age_group=actor.age, height=height_of(actor, where), build=actor.build,
                                    pose=actor.pose, clothing=actor.clothing, gender=actor.gender, where=where)
    except GarageError as exc:  # the library's `age_group` is the actor's `age`
        raise GarageError(str(exc).split(": ", 1)[1], exc.where.replace(".age_group", ".age")) from None
    return Entity(name=name, role=actor.role, pose=Pose(), shapes=[Mesh(body.glb)], model=body.name,
                  size_class=body.age_group, extent=body.extent, static=False, kind="person")


def height_of(actor, where: str) -> float | None:
    """A person's height (m): `height`, else its `stature` (0-1) across its age group's range (STATURE), to
    STATURE_STEP: each height (with each pose and outfit) is a body of its own, built once on disk in 5-40 s on a
    2-core CPU, so a continuous draw keeps to a few dozen heights."""
    from garage_exp.assets.people import STATURE

    if actor.stature is None:
        return actor.height
    share = float(actor.stature)
    if not 0.0 <= share <= 1.0:
        raise GarageError(f"stature {share:g} is outside 0-1", where + ".stature")
    low, high = STATURE.get(actor.age, STATURE["adult"])
    return round(round((low + share * (high - low)) / STATURE_STEP) * STATURE_STEP, 2)


def box_entity(name: str, actor, where: str) -> Entity:
    """A box of `length`, `width`, `height` in a colour; `colour: pillar` paints it as the garage's pillars
    (a striped band below, the pillar's paint above: the real look dresses both as it dresses the pillars)."""
    size = (float(actor.length or 1.0), float(actor.width or 0.3), float(actor.height or 1.0))
    if min(size) <= 0:
        raise GarageError(f"a box needs a positive size, got {size}", where)
    if actor.colour == "pillar":
        from garage_exp.scene import materials as mat
        from garage_exp.scene.structure import PILLAR_BAND_HEIGHT, banded_entity

        shapes = banded_entity(name, (0.0, 0.0), size[:2], size[2], PILLAR_BAND_HEIGHT, mat.PILLAR_BAND,
                               mat.PILLAR_PAINT).shapes
        return Entity(name=name, role=actor.role, pose=Pose(), shapes=shapes, extent=size, static=False, kind="box")
    try:
        rgb = BOX_COLOURS[actor.colour or "grey"]
    except KeyError:
        raise GarageError(f"unknown box colour {actor.colour!r} ({', '.join(BOX_COLOURS)}, pillar)",
                          f"{where}.colour") from None
    material = Material(f"box_{actor.colour or 'grey'}", (*rgb, 1.0), roughness=0.8)
    return Entity(name=name, role=actor.role, pose=Pose(), shapes=[Box(size, material, Pose(0.0, 0.0, size[2] / 2))],
                  extent=size, static=False, kind="box")
