"""Builds the SAPIEN entities of a `Scene` description: one registered converter per shape type, materials
shared per description material, static structure merged per material and tile.

Entities and ids: every vehicle (and every non-static entity) is its own SAPIEN entity, so the segmentation
picture's channel 1 (`per_scene_id`) says which vehicle a pixel shows (`ids`). Static structure, markings and
lamp fixtures are merged into one SAPIEN entity per material and 12 m tile (each box a shape of it): with 2,004
boxes at 640x480 one entity per material measured the same frame time as one entity per box (0.054-0.061 s vs
0.061-0.068 s, within noise); the tiles let a frame hide what it cannot see. An actor's decals (its contact
shadow) are a SAPIEN entity of their own, moved with it, so their pixels never carry the actor's id.

A new shape type of the scene description is one `sapien_shape.register` function here.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import replace
from functools import singledispatch

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE
from garage_exp.scene.description import VEHICLE_ROLES, Box, Decal, Entity, Material, Mesh, Pose, Texture

STATIC_ROLES = ("structure", "marking", "lamp")
STATIC_TILE = 12.0  # metres: static shapes merge per material and tile, so that frames can hide far tiles
DECALS = ":decals"  # suffix of the entity holding an actor's decals (its contact shadow)


def quat_yaw(yaw_deg: float) -> list[float]:
    """SAPIEN quaternion (w, x, y, z) of a rotation about +z."""
    half = math.radians(yaw_deg) / 2.0
    return [math.cos(half), 0.0, 0.0, math.sin(half)]


def sapien_pose(pose: Pose):
    import sapien

    return sapien.Pose([pose.x, pose.y, pose.z], quat_yaw(pose.yaw))


def merges(entity: Entity, batch_static: bool) -> bool:
    """Whether an entity's shapes go into the merged static bodies (no id of its own)."""
    return batch_static and entity.static and entity.role in STATIC_ROLES


def is_redrawn(entity: Entity) -> bool:
    """The statics a wide space's draw changes beyond their colours, whose merged bodies are rebuilt alone
    (`SceneBuilder.replace_redrawn`) while the rest of the garage stays loaded: line paint (markings of boxes,
    scene/markings.py: its pieces wear away with the lines' wear) and lamp fixtures (scene/lamps.py: which lamps
    have failed changes which panels share a material, and the merge groups shapes by material). Both are opaque
    boxes, so the order their bodies are drawn in changes no pixel."""
    if entity.role not in ("marking", "lamp"):
        return False
    return bool(entity.shapes) and all(isinstance(s, Box) for s in entity.shapes)


def static_key(merged: Iterable[Entity]) -> tuple[list, list]:
    """What merged static bodies are made of: their geometry (with each box's and decal's material left out, but
    for what its mesh is built from) and the materials of their boxes and decals in order."""
    merged = list(merged)
    # A wide space draws the floor's wetness and grime and the lines' wear per scenario: only the pictures change,
    # and a box's mesh depends on its picture only by whether it has one and its `tile` (the UVs' repeat; a
    # decal's span it once). So a picture is a material, changed in place (recolour) as a flat colour is, instead
    # of a full load of the garage (0.3 s a scenario on the wide space).
    geometry = [(e.name, e.pose, [replace(sh, material=_meshed(sh.material)) if _recoloured(sh) else sh
                                  for sh in e.shapes]) for e in merged]
    materials = [sh.material for e in merged for sh in e.shapes if _recoloured(sh)]
    return geometry, materials


def _recoloured(shape) -> bool:
    """A shape whose material can be changed in place: a box (flat or textured) or a decal."""
    return isinstance(shape, (Box, Decal))


def _meshed(material: Material) -> Texture | None:
    """What of a box's or decal's material its mesh is built from: none for a flat colour, the repeat of a
    picture."""
    return None if material.texture is None else Texture("", tile=material.texture.tile)


class SceneBuilder:
    """The SAPIEN entities, bodies and materials of one loaded SAPIEN scene, and how they were made."""

    def __init__(self, sapien_scene) -> None:
        self.scene = sapien_scene
        self.entities: dict[str, object] = {}  # name -> sapien.Entity, for entities with their own id
        self.bodies: dict[str, object] = {}  # name -> RenderBodyComponent
        self.merged: list[object] = []  # RenderBodyComponents of merged static entities
        self.ids: dict[str, int] = {}
        self.poses: dict[str, Pose] = {}
        self.vehicles: set[str] = set()
        self.materials: dict[Material, object] = {}  # one RenderMaterial per description material and load
        self.decal_ids: set[int] = set()  # bodies that are only decals (Frame.see_through)
        self.pillar_ids: set[int] = set()  # bodies that are only pillars (Frame.pillars)
        self.clamped: set[Material] = set()  # materials made for a decal (alpha below 1: SAPIEN's blended pass)
        self.redrawn: list[object] = []  # the merged bodies of line paint and lamps (is_redrawn): replace_redrawn
        self.redrawn_materials: set[Material] = set()  # their materials
        self._boxes: np.ndarray | None = None  # the merged bodies' world AABBs (merged_boxes)

    # ---- statics --------------------------------------------------------------------------------------------

    def add_statics(self, entities: Iterable[Entity]) -> None:
        """Merge static shapes per material and per STATIC_TILE square (by the shape's centre), so that a frame
        can hide the tiles outside its view; materials keep their order, meshes come last. The bodies of line
        paint and lamps are noted (`redrawn`): a load that changes only them rebuilds only them."""
        entities = list(entities)
        redrawn = {id(e) for e in entities if is_redrawn(e)}
        merged: dict[Material | None, dict[tuple[int, int], list[tuple[Pose, Box | Mesh, Entity]]]] = {}
        for entity in entities:
            for shape in entity.shapes:
                world = entity.pose.compose(shape.offset)
                key = shape.material if isinstance(shape, (Box, Decal)) else None
                tile = (math.floor(world.x / STATIC_TILE), math.floor(world.y / STATIC_TILE))
                merged.setdefault(key, {}).setdefault(tile, []).append((world, shape, entity))
        for material in [m for m in merged if m is not None] + ([None] if None in merged else []):
            for (a, b), shapes in merged[material].items():
                body = self._add_merged(f"static:{material.name if material else 'meshes'}:{a}:{b}", shapes)
                if all(id(entity) in redrawn for _, _, entity in shapes):
                    self.redrawn.append(body)
                    self.redrawn_materials.add(material)

    def replace_redrawn(self, entities: Iterable[Entity]) -> None:
        """Remove the merged bodies of line paint and lamps (and their materials) and merge the new ones: the
        garage's other bodies, the actors and the cameras stay. The caller replaces the actors afterwards, so that
        they come after the statics in SAPIEN's order as in a fresh build (`SapienRenderer._build`). Only when no
        other static shape has their materials (the renderer's key says so): then no body mixes the two."""
        gone = {id(body) for body in self.redrawn}
        for body in self.redrawn:
            self.scene.remove_entity(body.entity)
        if self._boxes is not None:  # the kept bodies' boxes stay (they never move); the new ones are read later
            self._boxes = self._boxes[[id(body) not in gone for body in self.merged[:len(self._boxes)]]]
        self.merged = [body for body in self.merged if id(body) not in gone]
        for material in self.redrawn_materials:
            self.materials.pop(material, None)
        self.redrawn, self.redrawn_materials = [], set()
        self.add_statics(entities)

    def merged_boxes(self) -> np.ndarray:
        """The merged static bodies' world AABBs (n, 2, 3), in `merged` order: they never move, so each is read
        from SAPIEN once (about 700 bodies: 0.04 s a load) rather than on every actors' replacement. The boxes
        kept are those of a prefix of `merged` (statics are appended; replace_redrawn drops the removed ones' and
        a wide space's draw, whose wear rebuilds the line paint, reads only the new bodies')."""
        known = 0 if self._boxes is None else len(self._boxes)
        if self._boxes is None or known < len(self.merged):
            new = np.array([body.get_global_aabb_fast() for body in self.merged[known:]],
                           dtype=float).reshape(-1, 2, 3)
            self._boxes = new if self._boxes is None else np.concatenate([self._boxes, new])
        return self._boxes

    def _add_merged(self, name: str, shapes: Sequence[tuple[Pose, Box | Mesh, Entity]]):
        import sapien
        import sapien.render as sr

        body = sr.RenderBodyComponent()
        for world, shape, _ in shapes:
            body.attach(self.shape(shape, world, name, world))
        node = sapien.Entity()
        node.name = name
        node.add_component(body)
        self.scene.add_entity(node)
        self.merged.append(body)
        if all(isinstance(shape, Decal) for _, shape, _ in shapes):
            self.decal_ids.add(int(node.per_scene_id))
        # Pillars have materials of their own (pillar_paint, pillar_band), so a body holds pillars only or none.
        if all(entity.is_pillar for _, _, entity in shapes):
            self.pillar_ids.add(int(node.per_scene_id))
        return body

    def recolour(self, change: dict[Material, Material]) -> None:
        """Give each loaded RenderMaterial its new values and picture, as `material` would make it for the new
        material; shapes keep their material objects."""
        moved = {}
        for old, new in change.items():
            rm = self.materials[old]
            if old != new:
                colour = list(new.color)
                if old in self.clamped:
                    colour[3] = min(colour[3], 0.999)
                rm.set_base_color(colour)
                rm.set_emission([*new.emission, 1.0])
                rm.set_roughness(new.roughness)
                rm.set_metallic(new.metallic)
                rm.set_specular(new.specular)
                if new.texture is not None:
                    _texture(rm, new)
                    if _uploaded(new)[1] is None:
                        rm.roughness_texture = None  # a fresh material of a picture without one has none
            moved[new] = rm
        self.clamped = (self.clamped - change.keys()) | {new for old, new in change.items() if old in self.clamped}
        self.redrawn_materials = {change.get(m, m) for m in self.redrawn_materials}
        # rebuilt at once: a swap (A -> B, B -> A) must not read a value written in this loop
        self.materials = {**{m: rm for m, rm in self.materials.items() if m not in change}, **moved}

    def restyle(self, change: dict[Material, Material]) -> None:
        """Give loaded textured materials other pictures: the shapes keep their SAPIEN materials, whose textures
        are replaced."""
        for old, new in change.items():
            rm = self.materials.pop(old, None)
            if rm is None:
                continue
            if new.texture is not None and new != old:
                _texture(rm, new)
            self.materials[new] = rm

    # ---- actors ---------------------------------------------------------------------------------------------

    def add_entity(self, entity: Entity) -> None:
        """An entity with its own id (and its decals, if any, as a second entity moved with it)."""
        import sapien
        import sapien.render as sr

        if entity.name in self.entities:
            raise GarageError(f"two entities are named {entity.name!r}", "scene")
        body = sr.RenderBodyComponent()
        for shape in entity.shapes:
            if not isinstance(shape, Decal):
                body.attach(self.shape(shape, shape.offset, entity.name, entity.pose.compose(shape.offset)))
        node = sapien.Entity()
        node.name = entity.name
        node.add_component(body)
        node.set_pose(sapien_pose(entity.pose))
        self.scene.add_entity(node)
        self.entities[entity.name] = node
        self.bodies[entity.name] = body
        self.ids[entity.name] = int(node.per_scene_id)
        self.poses[entity.name] = entity.pose
        if entity.is_pillar:  # a pillar with its own id (renderer.batch_static=false)
            self.pillar_ids.add(int(node.per_scene_id))
        if entity.role in VEHICLE_ROLES:
            self.vehicles.add(entity.name)
        decals = [shape for shape in entity.shapes if isinstance(shape, Decal)]
        if decals:
            # Its own SAPIEN entity, moved with the actor: the shadow's pixels never carry the actor's id.
            under = sr.RenderBodyComponent()
            for shape in decals:
                under.attach(self.shape(shape, shape.offset, entity.name))
            holder = sapien.Entity()
            holder.name = entity.name + DECALS
            holder.add_component(under)
            holder.set_pose(sapien_pose(entity.pose))
            self.scene.add_entity(holder)
            self.decal_ids.add(int(holder.per_scene_id))
            self.entities[holder.name] = holder
            self.bodies[holder.name] = under

    def remove_actors(self) -> None:
        """Remove every entity with its own id; the merged statics and the materials stay."""
        for node in self.entities.values():
            self.decal_ids.discard(int(node.per_scene_id))  # before the removal, which sets the id to 0
            self.pillar_ids.discard(int(node.per_scene_id))
            self.scene.remove_entity(node)
        self.entities, self.bodies, self.ids, self.poses, self.vehicles = {}, {}, {}, {}, set()

    def set_pose(self, name: str, pose: Pose) -> list[str]:
        """Move an entity with its own id and its decals; the names of the entities moved."""
        node = self.entities.get(name)
        if node is None:
            raise GarageError(f"no movable entity named {name!r} in the loaded scene", "renderer.set_pose")
        node.set_pose(sapien_pose(pose))
        self.poses[name] = pose
        under = self.entities.get(name + DECALS)
        if under is None:
            return [name]
        under.set_pose(sapien_pose(pose))
        return [name, name + DECALS]

    # ---- shapes and materials -------------------------------------------------------------------------------

    def shape(self, shape: Box | Mesh | Decal, local: Pose, owner: str, world: Pose | None = None):
        """One SAPIEN shape at `local` in its body; `world` is where that puts it (textures map by world
        position, so boxes side by side continue one another's picture)."""
        out = sapien_shape(shape, self, owner, world or local)
        out.local_pose = sapien_pose(local)
        return out

    def material(self, material: Material, decal: bool = False):
        import sapien.render as sr

        if material not in self.materials:
            colour = list(material.color)
            if decal:
                colour[3] = min(colour[3], 0.999)  # alpha below 1: SAPIEN's blended (transparent) pass
                self.clamped.add(material)
            rm = sr.RenderMaterial(emission=[*material.emission, 1.0], base_color=colour,
                                   roughness=material.roughness, metallic=material.metallic,
                                   specular=material.specular)
            if material.texture is not None:
                _texture(rm, material)
            self.materials[material] = rm
        return self.materials[material]


@singledispatch
def sapien_shape(shape, builder: SceneBuilder, owner: str, world: Pose):
    """The SAPIEN render shape of one description shape (its local pose is set by the caller)."""
    raise GarageError(f"the SAPIEN renderer cannot draw a {type(shape).__name__}", owner)


@sapien_shape.register
def _(shape: Decal, builder: SceneBuilder, owner: str, world: Pose):
    import sapien.render as sr

    return sr.RenderShapeTriangleMesh(*_decal_mesh(shape.size), builder.material(shape.material, decal=True))


@sapien_shape.register
def _(shape: Box, builder: SceneBuilder, owner: str, world: Pose):
    import sapien.render as sr

    if min(shape.size) <= 0:  # plain Python: np.any on 3 numbers was a fifth of a 26,000-box load
        raise GarageError(f"box size {shape.size} must be positive", owner)
    if shape.material.texture is not None:
        mesh = _box_mesh(shape.size, world, shape.material.texture.tile)
        return sr.RenderShapeTriangleMesh(*mesh, builder.material(shape.material))
    half = np.asarray(shape.size, dtype=np.float32) / 2.0
    return sr.RenderShapeBox(half, builder.material(shape.material))


@sapien_shape.register
def _(shape: Mesh, builder: SceneBuilder, owner: str, world: Pose):
    """A mesh file. SAPIEN caches models by file name for as long as its engine lives (device.py keeps it):
    30 GLB cars load in ~0.5 s the first time and ~0.03 s in every later scene, so no cache here."""
    import sapien.render as sr

    path = os.path.abspath(shape.path)
    if not os.path.isfile(path):
        raise GarageError(f"mesh file {shape.path} does not exist", owner)
    try:
        mesh = sr.RenderShapeTriangleMesh(path, np.full(3, shape.scale, dtype=np.float32))
    except RuntimeError as exc:
        raise GarageError(f"SAPIEN could not load mesh {shape.path} ({exc})", owner) from exc
    if shape.paint is not None:  # each loaded shape has its own materials (the file's geometry is shared)
        for part in mesh.parts:
            _paint(part.material, shape.paint)
    return mesh


def _paint(rm, paint: tuple[float, float, float]) -> None:
    """A vehicle's paint multiplied into its material. SAPIEN's shader takes a part's texture instead of its base
    colour (a factor set beside a texture does nothing), so a textured part gets a painted copy of its texture,
    multiplied in linear light; the model's own texture, which other cars of the model share, stays as it was."""
    import sapien.render as sr

    texture = rm.base_color_texture
    if texture is None:
        rm.set_base_color([*paint, 1.0])
        return
    pixels = texture.download()
    linear = _SRGB_TO_LINEAR[pixels[..., :3]] * np.asarray(paint, np.float32)
    encoded = np.where(linear <= 0.0031308, linear * 12.92, 1.055 * np.power(linear, 1 / 2.4) - 0.055)
    out = pixels.copy()
    out[..., :3] = np.rint(np.clip(encoded, 0.0, 1.0) * 255.0).astype(np.uint8)
    rm.base_color_texture = sr.RenderTexture2D(np.ascontiguousarray(out), "R8G8B8A8Unorm",
                                               mipmap_levels=texture.mipmap_levels, srgb=True)


_LEVELS = np.arange(256, dtype=np.float32) / 255.0
_SRGB_TO_LINEAR = np.where(_LEVELS <= 0.04045, _LEVELS / 12.92, ((_LEVELS + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _texture(rm, material: Material) -> None:
    """Give a SAPIEN material its procedural picture (8-bit sRGB with mipmaps: a far floor does not shimmer)."""
    base, rough = _uploaded(material)
    rm.base_color_texture = base
    if rough is not None:
        rm.roughness_texture = rough


# A search on generated garages loads another garage (or the same with another floor) at nearly every trial: each
# full load made all its ~100 textures again (79 of them bay-number signs) and uploaded them, ~0.3 s a load, as the
# pictures' own cache (scene.textures, 128) holds one garage's. The uploaded textures are kept instead, by material
# (its picture's kind, seed and parameters): the garages' signs and walls are shared, only a new floor is made.
# SAPIEN's textures are read-only once made (a painted car makes a copy, restyle() replaces one), so materials of
# several scenes may share one. 512 at most (8-bit; ~0.1 MB a sign, a few MB a floor).
UPLOADS_KEPT = 512


@STATE.memo("process", maxsize=UPLOADS_KEPT)
def _uploaded(material: Material) -> tuple:
    """The material's picture uploaded: (base colour texture, roughness texture or None)."""
    import sapien.render as sr

    from garage_exp.scene.textures import image, image8

    rgba, rough = image(material)
    levels = max(1, int(math.log2(min(rgba.shape[:2]))) - 1)
    base = sr.RenderTexture2D(np.ascontiguousarray(image8(material)), "R8G8B8A8Unorm", mipmap_levels=levels, srgb=True)
    if rough is not None:
        rough = sr.RenderTexture2D(np.ascontiguousarray(rough, dtype=np.float32)[..., None], "R32Sfloat",
                                   mipmap_levels=levels)
    return base, rough


def _box_mesh(size: Sequence[float], world: Pose, tile: float):
    """A box as a triangle mesh (vertices, triangles, normals, uvs) in its own frame, its UVs mapped by world
    position (scene/boxmesh.box_uvs)."""
    from garage_exp.scene.boxmesh import UNIT_CORNERS, UNIT_FACES, UNIT_NORMALS, box_uvs

    local = UNIT_CORNERS * np.asarray(size, dtype=float)
    c, s = math.cos(math.radians(world.yaw)), math.sin(math.radians(world.yaw))
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    uv = box_uvs(local @ rot.T + np.array([world.x, world.y, world.z]), UNIT_NORMALS @ rot.T, tile)
    return (local.astype(np.float32), UNIT_FACES.astype(np.uint32), UNIT_NORMALS.astype(np.float32),
            uv.astype(np.float32))


def _decal_mesh(size: Sequence[float]):
    from garage_exp.scene.boxmesh import quad

    vertices, triangles, normals, uvs = quad(size)
    return (vertices.astype(np.float32), triangles.astype(np.uint32), normals.astype(np.float32),
            uvs.astype(np.float32))
