"""SAPIEN 3 backend: builds a SAPIEN scene from a `Scene` description and renders its cameras.

One renderer per process (`get_renderer()`): the first frame of a process compiles SAPIEN's shaders (3-7 s
measured on lavapipe here) and every later scene reuses them, provided SAPIEN's engine outlives the scenes
(`device.ensure_device` holds it), so a job loads its scene into the existing renderer.

Entities and ids: every vehicle (and every non-static entity) is its own SAPIEN entity, so the segmentation
picture's channel 1 (`per_scene_id`) says which vehicle a pixel shows (`renderer.ids`). Static structure,
markings and lamp fixtures are merged into one SAPIEN entity per material and 12 m tile (each box a shape of
it): with 2,004 boxes at 640x480 one entity per material measured the same frame time as one entity per box
(0.054-0.061 s vs 0.061-0.068 s, within noise); the tiles let a frame hide what it cannot see.
`batch_static=False` keeps an id per structure entity.

Culling (`cull=True`): each frame hides the bodies whose world AABB lies wholly outside the camera's frustum
(render/cull.py), which cover no pixel, and ground truth's silhouette candidates are filtered by the same
test. Only bodies whose visibility changes are touched. With shadows on nothing is culled (a body out of view
can cast a shadow into it). benchmarks/RESULTS.md (issue 13) has the measured gain: frames and ground truth
are byte-identical.

Lights: SAPIEN's default shader is compiled for a fixed number of point lights (at most 10), and changing the
count recompiles it. The renderer keeps a fixed pool of `max_lights` point lights in every scene and, before
each frame, gives them to the lamps that contribute most at the camera (intensity / distance^2); spare pool
lights get zero colour. Every lamp fixture is drawn as an emissive box whether or not it holds a pool light.
Shadows (`shadows=True`) go to the 3 strongest pool lights (SAPIEN's limit): measured 0.144 s vs 0.047 s a
frame (3x; 2.6x with 128 px shadow maps), so they are off by default.

Silhouettes (`unoccluded_ids`): a second camera per camera spec with SAPIEN's unlit "minimal" shader renders
ids only (about half the cost of a lit frame; same rasterisation, pixel-identical ids), with every other body
hidden.

Blank control (`Scene.background=False`): everything but the vehicles is hidden and empty pixels become
grey 128. This is what "the same vehicle with the background removed" means: the whole vehicle, lit by the
same lights, with the garage (pillars included) gone. `render.composite.blank_composite` pastes only given
vehicles' pixels on grey: on a blank render it drops the other vehicles; on a full render it would keep the target cut by its
occluders, which is occlusion without background rather than the control.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from garage_exp.core.state import STATE
from garage_exp.core.errors import GarageError
from garage_exp.render.base import BLANK_GREY, Frame
from garage_exp.render.cull import box_corners, frustum_planes, outside_frustum
from garage_exp.render.device import ensure_device
from garage_exp.render.fisheye import (CubeMap, Fisheye, Pinhole, cube_map, face_rotation, lens_of, lookup,
                                      remap_bilinear, view_lens, view_remap)
from garage_exp.scene.camera import camera_to_world, intrinsics_of, to_camera, to_pixels
from garage_exp.scene.description import VEHICLE_ROLES, Box, CameraSpec, Decal, Entity, Material, Mesh, Pose, Scene

# SAPIEN's point light adds albedo * colour * cos / (pi * d^2): a description intensity of 1.0 (a ~40 W LED
# batten) becomes a colour of LAMP_POWER, which lights a grey (0.5) floor 2.5 m below one lamp to ~0.25
# linear (~140 of 255 after the shader's 1/2.2 gamma).
LAMP_POWER = 10.0
SHADOW_MAP_SIZE = 512  # per cube face; lavapipe renders all six faces of every shadowed light each frame
SHADOW_NEAR, SHADOW_FAR = 0.05, 30.0
MAX_SHADOWED = 3  # SAPIEN's default shader: "too many point lights that cast shadows" beyond this
STATIC_ROLES = ("structure", "marking", "lamp")
STATIC_TILE = 12.0  # metres: static shapes merge per material and tile, so that frames can hide far tiles
DECALS = ":decals"  # suffix of the entity holding an actor's decals (its contact shadow)


@dataclass
class _Camera:
    spec: CameraSpec
    component: object  # sapien.render.RenderCameraComponent with the default (lit) shader
    silhouette: object  # the same camera with the unlit "minimal" shader: ids only, about half the cost
    # A fisheye camera has no picture of its own: its cube faces (rotation in the camera's frame, a pinhole
    # _Camera) are rendered and remapped (render/fisheye.py); `view` undistorts the result for the detector.
    faces: list[tuple[np.ndarray, "_Camera"]] | None = None
    crop: tuple[int, int, int, int] | None = None  # a cube face's rendered rectangle (x0, y0, w, h); spec: whole face
    cube: CubeMap | None = None
    lens: Fisheye | None = None
    view: tuple | None = None  # (view lens, cv2 map_x, map_y, nearest flat index) or None for the raw image


def quat_yaw(yaw_deg: float) -> list[float]:
    """SAPIEN quaternion (w, x, y, z) of a rotation about +z."""
    half = math.radians(yaw_deg) / 2.0
    return [math.cos(half), 0.0, 0.0, math.sin(half)]


def _sapien_pose(pose: Pose):
    import sapien

    return sapien.Pose([pose.x, pose.y, pose.z], quat_yaw(pose.yaw))


class SapienRenderer:
    """Renders `Scene` descriptions with SAPIEN. Reuse one instance (see `get_renderer`)."""

    def __init__(self, max_lights: int = 8, shadows: bool = False, batch_static: bool = True, cull: bool = True,
                 device: str = "auto"):
        self.device = device  # renderer.device: auto | cpu | cuda (device.ensure_device)
        self.max_lights = max_lights
        self.shadows = shadows
        self.batch_static = batch_static
        self.cull = cull
        self.description: Scene | None = None
        self._scene = None  # sapien.Scene
        self._entities: dict[str, object] = {}  # name -> sapien.Entity, for entities with their own id
        self._bodies: dict[str, object] = {}  # name -> RenderBodyComponent
        self._merged: list[object] = []  # RenderBodyComponents of merged static entities
        self._ids: dict[str, int] = {}
        self._poses: dict[str, Pose] = {}
        self._vehicles: set[str] = set()
        self._ego: str | None = None
        self._cameras: dict[str, _Camera] = {}
        self._pool: list[object] = []  # RenderPointLightComponents
        self._lamp_pos = np.zeros((0, 3))
        self._lamp_rgb = np.zeros((0, 3))
        self._lamp_weight = np.zeros(0)
        self._materials: dict[Material, object] = {}  # one RenderMaterial per description material and load
        self._decal_ids: set[int] = set()  # bodies that are only decals (Frame.see_through)
        self._restyled = False  # restyle() swapped pictures since the last full load
        self._static: tuple | None = None  # what the loaded static bodies were built from (see load)
        self._reset_bodies()

    def _reset_bodies(self) -> None:
        # Every body, in one order: what it shows without culling (`_base`), what it shows now (`_shown`) and
        # its world AABB (`_lo`, `_hi`; a moved entity's is refreshed before the next render).
        self._all: list[object] = []
        self._index: dict[str, int] = {}  # entity name -> position in _all
        self._base = np.zeros(0, dtype=bool)
        self._shown = np.zeros(0, dtype=bool)
        self._lo, self._hi = np.zeros((0, 3)), np.zeros((0, 3))
        self._moved: set[str] = set()
        self.culled = 0  # bodies the last render() hid as outside the frustum

    # ---- building -------------------------------------------------------------------------------------------

    def load(self, scene: Scene) -> None:
        """(Re)build the SAPIEN scene from a description; cameras, lights and ids are replaced. When the static
        structure, lamps and settings are those already loaded (the trials of a search, which change only the
        actors), only the actors and cameras are replaced: the merged static bodies stay."""
        ensure_device(self.device)
        import sapien

        static = self._static_key(scene)
        # A restyled scene (a replicate's pictures) no longer shows its description's materials: rebuild it.
        recolour = self._recolouring(static) if self._scene is not None and not self._restyled else None
        if recolour is not None:
            try:
                self._recolour(recolour)
                self._replace_actors(scene)
            except BaseException:
                self._reset()
                raise
            self.description, self._static = scene, static
            return
        self._reset()
        try:
            self._scene = sapien.Scene()
        except RuntimeError as exc:
            raise GarageError(f"SAPIEN could not create a scene ({exc})", "renderer") from exc
        try:
            self._build(scene)
        except BaseException:
            self._reset()  # never leave a half-built scene to render
            raise
        self.description = scene
        self._static = static

    def _static_key(self, scene: Scene) -> tuple:
        """What the merged static bodies are made of: their geometry (with each shape's material left out), the
        materials of their shapes in order, and the settings. Lamps and ambient light are set on every load."""
        merged = [e for e in scene.entities if self._merges(e)]
        # A textured material's picture is part of the geometry (a mesh with UVs): it is not recoloured.
        geometry = [(e.name, e.pose, [replace(sh, material=None) if _plain(sh) else sh for sh in e.shapes])
                    for e in merged]
        materials = [sh.material for e in merged for sh in e.shapes if _plain(sh)]
        return (geometry, materials, scene.background, self.max_lights, self.shadows, self.batch_static)

    def _recolouring(self, static: tuple) -> dict[Material, Material] | None:
        """When the new statics are the loaded ones with other materials (a search's light intensity changes
        the lamp panels' glow), the old -> new material map that turns one into the other; None when they
        differ otherwise (a full load), or when one old material would need two new ones (lamps switched on
        or off: the merge groups shapes by material)."""
        if self._static is None or static[0] != self._static[0] or static[2:] != self._static[2:]:
            return None
        change: dict[Material, Material] = {}
        for old, new in zip(self._static[1], static[1]):
            if change.setdefault(old, new) != new:
                return None
        return change

    def _recolour(self, change: dict[Material, Material]) -> None:
        """Give each loaded RenderMaterial its new values; shapes keep their material objects."""
        moved = {}
        for old, new in change.items():
            rm = self._materials[old]
            if old != new:
                rm.set_base_color(list(new.color))
                rm.set_emission([*new.emission, 1.0])
                rm.set_roughness(new.roughness)
                rm.set_metallic(new.metallic)
                rm.set_specular(new.specular)
            moved[new] = rm
        # rebuilt at once: a swap (A -> B, B -> A) must not read a value written in this loop
        self._materials = {**{m: rm for m, rm in self._materials.items() if m not in change}, **moved}

    def restyle(self, change: dict[Material, Material]) -> None:
        """Give loaded textured materials other pictures (a replicate's stains and wetness): the shapes keep
        their SAPIEN materials, whose textures are replaced; nothing is rebuilt."""
        self._restyled = self._restyled or bool(change)
        for old, new in change.items():
            rm = self._materials.pop(old, None)
            if rm is None:
                continue
            if new.texture is not None and new != old:
                _texture(rm, new)
            self._materials[new] = rm

    def _merges(self, entity: Entity) -> bool:
        return self.batch_static and entity.static and entity.role in STATIC_ROLES

    def _replace_actors(self, scene: Scene) -> None:
        """Remove every entity with its own id and every camera, add the new scene's; the merged statics and
        the light pool stay (shown again in full: the last frame may have culled some)."""
        for node in self._entities.values():
            self._decal_ids.discard(int(node.per_scene_id))  # before the removal, which sets the id to 0
            self._scene.remove_entity(node)
        for cam in self._cameras.values():
            for _, pinhole in cam.faces or [(None, cam)]:  # a fisheye's cube faces are cameras of their own
                self._scene.remove_entity(pinhole.component.entity)
                self._scene.remove_entity(pinhole.silhouette.entity)
        self._entities, self._bodies, self._ids, self._poses, self._vehicles, self._cameras = {}, {}, {}, {}, set(), {}
        for body in self._merged:
            body.visibility = 1.0
        self._scene.set_ambient_light([float(c) for c in scene.ambient])
        self._set_lamps(scene)
        for entity in scene.entities:
            if not self._merges(entity):
                self._add_entity(entity)
        self._mount_cameras(scene)
        self._index_bodies(scene)

    def _build(self, scene: Scene) -> None:
        self._scene.set_ambient_light([float(c) for c in scene.ambient])
        # Static shapes merge per material and per STATIC_TILE square (by the shape's centre), so that a frame
        # can hide the tiles outside its view; materials keep their order.
        merged: dict[Material | None, dict[tuple[int, int], list[tuple[Pose, Box | Mesh]]]] = {}
        for entity in scene.entities:
            if self._merges(entity):
                for shape in entity.shapes:
                    world = entity.pose.compose(shape.offset)
                    key = shape.material if isinstance(shape, (Box, Decal)) else None
                    tile = (math.floor(world.x / STATIC_TILE), math.floor(world.y / STATIC_TILE))
                    merged.setdefault(key, {}).setdefault(tile, []).append((world, shape))
        for material in [m for m in merged if m is not None] + ([None] if None in merged else []):
            for (a, b), shapes in merged[material].items():
                self._add_merged(f"static:{material.name if material else 'meshes'}:{a}:{b}", shapes)
        # The actors after the statics, as _replace_actors adds them to a scene it keeps: SAPIEN draws bodies in
        # the order they were added, and where an actor's contact shadow meets a pillar's (both decals at
        # SHADOW_Z, blended) the later one is drawn over the other. Any other order gave a search's trials
        # (statics kept) other pixels than the same job loaded fresh (issue 31, item 3).
        for entity in scene.entities:
            if not self._merges(entity):
                self._add_entity(entity)
        self._mount_cameras(scene)
        self._add_lights(scene)
        self._index_bodies(scene)

    def _mount_cameras(self, scene: Scene) -> None:
        egos = [e.name for e in scene.entities if e.role == "ego"]
        self._ego = egos[0] if egos else None
        if scene.cameras and self._ego is None:
            raise GarageError("the scene has cameras but no entity with role 'ego' to mount them on", scene.name)
        for spec in scene.cameras:
            self._add_camera(spec)

    def _index_bodies(self, scene: Scene) -> None:
        # The blank control: everything but the vehicles is hidden (also from the silhouette renders).
        self._all = [*self._bodies.values(), *self._merged]
        self._index = {name: k for k, name in enumerate(self._bodies)}
        self._base = np.array([scene.background or name in self._vehicles for name in self._bodies]
                              + [scene.background] * len(self._merged), dtype=bool)
        self._shown = np.ones(len(self._all), dtype=bool)
        self._show_only(self._base)
        boxes = np.array([body.get_global_aabb_fast() for body in self._all], dtype=float).reshape(-1, 2, 3)
        self._lo, self._hi = boxes[:, 0].copy(), boxes[:, 1].copy()

    def _reset(self) -> None:
        self._scene, self.description, self._static = None, None, None
        self._entities, self._bodies, self._merged, self._materials = {}, {}, [], {}
        self._decal_ids = set()
        self._restyled = False
        self._ids, self._poses, self._vehicles, self._cameras, self._pool = {}, {}, set(), {}, []
        self._reset_bodies()

    def _add_entity(self, entity: Entity) -> None:
        import sapien
        import sapien.render as sr

        if entity.name in self._entities:
            raise GarageError(f"two entities are named {entity.name!r}", "scene")
        body = sr.RenderBodyComponent()
        for shape in entity.shapes:
            if not isinstance(shape, Decal):
                body.attach(self._shape(shape, shape.offset, entity.name, entity.pose.compose(shape.offset)))
        node = sapien.Entity()
        node.name = entity.name
        node.add_component(body)
        node.set_pose(_sapien_pose(entity.pose))
        self._scene.add_entity(node)
        self._entities[entity.name] = node
        self._bodies[entity.name] = body
        self._ids[entity.name] = int(node.per_scene_id)
        self._poses[entity.name] = entity.pose
        if entity.role in VEHICLE_ROLES:
            self._vehicles.add(entity.name)
        decals = [shape for shape in entity.shapes if isinstance(shape, Decal)]
        if decals:
            # Its own SAPIEN entity, moved with the actor: the shadow's pixels never carry the actor's id.
            under = sr.RenderBodyComponent()
            for shape in decals:
                under.attach(self._shape(shape, shape.offset, entity.name))
            holder = sapien.Entity()
            holder.name = entity.name + DECALS
            holder.add_component(under)
            holder.set_pose(_sapien_pose(entity.pose))
            self._scene.add_entity(holder)
            self._decal_ids.add(int(holder.per_scene_id))
            self._entities[holder.name] = holder
            self._bodies[holder.name] = under

    def _add_merged(self, name: str, shapes: Sequence[tuple[Pose, Box | Mesh]]) -> None:
        import sapien
        import sapien.render as sr

        body = sr.RenderBodyComponent()
        for world, shape in shapes:
            body.attach(self._shape(shape, world, name, world))
        node = sapien.Entity()
        node.name = name
        node.add_component(body)
        self._scene.add_entity(node)
        self._merged.append(body)
        if all(isinstance(shape, Decal) for _, shape in shapes):
            self._decal_ids.add(int(node.per_scene_id))

    def _shape(self, shape: Box | Mesh | Decal, local: Pose, owner: str, world: Pose | None = None):
        """One SAPIEN shape at `local` in its body; `world` is where that puts it (textures map by world
        position, so boxes side by side continue one another's picture)."""
        import sapien.render as sr

        if isinstance(shape, Decal):
            out = sr.RenderShapeTriangleMesh(*_decal_mesh(shape.size), self._material(shape.material, decal=True))
        elif isinstance(shape, Box):
            if min(shape.size) <= 0:  # plain Python: np.any on 3 numbers was a fifth of a 26,000-box load
                raise GarageError(f"box size {shape.size} must be positive", owner)
            if shape.material.texture is not None:
                mesh = _box_mesh(shape.size, world or local, shape.material.texture.tile)
                out = sr.RenderShapeTriangleMesh(*mesh, self._material(shape.material))
            else:
                half = np.asarray(shape.size, dtype=np.float32) / 2.0
                out = sr.RenderShapeBox(half, self._material(shape.material))
        else:
            out = self._mesh(shape, owner)
        out.local_pose = _sapien_pose(local)
        return out

    def _material(self, material: Material, decal: bool = False):
        import sapien.render as sr

        if material not in self._materials:
            colour = list(material.color)
            if decal:
                colour[3] = min(colour[3], 0.999)  # alpha below 1: SAPIEN's blended (transparent) pass
            rm = sr.RenderMaterial(emission=[*material.emission, 1.0], base_color=colour,
                                   roughness=material.roughness, metallic=material.metallic,
                                   specular=material.specular)
            if material.texture is not None:
                _texture(rm, material)
            self._materials[material] = rm
        return self._materials[material]

    def _mesh(self, mesh: Mesh, owner: str):
        """A mesh shape. SAPIEN caches models by file name for as long as its engine lives (device.py keeps it):
        30 GLB cars load in ~0.5 s the first time and ~0.03 s in every later scene, so no cache here."""
        import sapien.render as sr

        path = os.path.abspath(mesh.path)
        if not os.path.isfile(path):
            raise GarageError(f"mesh file {mesh.path} does not exist", owner)
        try:
            return sr.RenderShapeTriangleMesh(path, np.full(3, mesh.scale, dtype=np.float32))
        except RuntimeError as exc:
            raise GarageError(f"SAPIEN could not load mesh {mesh.path} ({exc})", owner) from exc

    def _add_camera(self, spec: CameraSpec) -> None:
        if spec.name in self._cameras:
            raise GarageError(f"two cameras are named {spec.name!r}", "scene.cameras")
        if spec.fisheye:
            self._cameras[spec.name] = self._fisheye_camera(spec)
        else:
            self._cameras[spec.name] = self._pinhole_camera(spec)

    def _pinhole_camera(self, spec: CameraSpec, crop: tuple[int, int, int, int] | None = None) -> _Camera:
        """A camera and its silhouette twin; `crop` renders only that rectangle of the spec's image (an
        off-centre pinhole with the spec's focal length), for cube faces."""
        import sapien
        import sapien.render as sr

        width, height = (crop[2], crop[3]) if crop else (spec.width, spec.height)
        component = self._scene.add_camera(spec.name, width, height, math.radians(spec.fovy), spec.near, spec.far)
        silhouette = sr.RenderCameraComponent(width, height, _minimal_shader_dir())
        silhouette.set_fovy(math.radians(spec.fovy), compute_x=True)
        silhouette.near, silhouette.far = spec.near, spec.far
        if crop:
            fx, fy, cx, cy = intrinsics_of(spec)
            for cam in (component, silhouette):
                cam.set_perspective_parameters(spec.near, spec.far, fx, fy, cx - crop[0], cy - crop[1], 0.0)
        mount = sapien.Entity()
        mount.name = f"{spec.name}:silhouette"
        mount.add_component(silhouette)
        self._scene.add_entity(mount)
        return _Camera(spec, component, silhouette, crop=crop)

    def _fisheye_camera(self, spec: CameraSpec) -> _Camera:
        """The cube faces the lens sees, each a pinhole camera at the size the fisheye needs (render/fisheye.py)."""
        lens = lens_of(spec)
        cube = cube_map(lens)
        faces = []
        for k, face in enumerate(cube.faces):
            size = cube.sizes[k]
            face_spec = CameraSpec(f"{spec.name}:{face}", spec.mount, pitch=spec.pitch, fovy=cube.face_fovy(k),
                                   width=size, height=size, near=spec.near, far=spec.far)
            rot = np.eye(4)
            rot[:3, :3] = face_rotation(face)
            faces.append((rot, self._pinhole_camera(face_spec, cube.crops[k])))
        target = view_lens(spec)
        view = (target, *view_remap(lens, target)) if target is not None else None
        first = faces[0][1]
        return _Camera(spec, first.component, first.silhouette, faces=faces, cube=cube, lens=lens, view=view)

    def _set_lamps(self, scene: Scene) -> None:
        """The lamps the pool's lights go to, frame by frame (see choose_lights)."""
        lights = [light for light in scene.lights if light.intensity > 0]
        self._lamp_pos = np.array([light.position for light in lights], dtype=float).reshape(-1, 3)
        self._lamp_rgb = np.array([np.asarray(light.color) * light.intensity * LAMP_POWER for light in lights],
                                  dtype=float).reshape(-1, 3)
        self._lamp_weight = np.array([light.intensity for light in lights], dtype=float)

    def _add_lights(self, scene: Scene) -> None:
        self._set_lamps(scene)
        for k in range(self.max_lights):
            # The pool is filled strongest first, so with shadows on the lamps nearest the camera cast them.
            self._pool.append(self._scene.add_point_light(
                [0.0, 0.0, -100.0], [0.0, 0.0, 0.0], shadow=self.shadows and k < MAX_SHADOWED,
                shadow_near=SHADOW_NEAR, shadow_far=SHADOW_FAR, shadow_map_size=SHADOW_MAP_SIZE))

    # ---- per frame ------------------------------------------------------------------------------------------

    @property
    def ids(self) -> dict[str, int]:
        """Entity name -> segmentation id (`per_scene_id`) for every entity with its own id."""
        return dict(self._ids)

    @property
    def poses(self) -> dict[str, Pose]:
        return dict(self._poses)

    def set_pose(self, name: str, pose: Pose) -> None:
        """Move an entity that has its own id (vehicles, the ego: the cameras follow the ego)."""
        node = self._entities.get(name)
        if node is None:
            raise GarageError(f"no movable entity named {name!r} in the loaded scene", "renderer.set_pose")
        node.set_pose(_sapien_pose(pose))
        self._poses[name] = pose
        self._moved.add(name)
        under = self._entities.get(name + DECALS)
        if under is not None:
            under.set_pose(_sapien_pose(pose))
            self._moved.add(name + DECALS)

    def camera_pose(self, camera_name: str) -> np.ndarray:
        return camera_to_world(self._poses[self._ego], self._camera(camera_name).spec)

    def choose_lights(self, position: Sequence[float]) -> np.ndarray:
        """Indices of the lamps that get the pool's lights at this camera position (largest intensity/d^2)."""
        if len(self._lamp_pos) == 0:
            return np.zeros(0, dtype=int)
        d2 = np.sum((self._lamp_pos - np.asarray(position, dtype=float)) ** 2, axis=1)
        score = self._lamp_weight / np.maximum(d2, 1e-6)
        n = min(self.max_lights, len(score))
        best = np.argpartition(-score, n - 1)[:n]
        return best[np.argsort(-score[best], kind="stable")]

    def render(self, camera_name: str) -> Frame:
        """Render one camera: colour and entity ids, with the camera's pose and intrinsics."""
        cam = self._camera(camera_name)
        pose = self.camera_pose(camera_name)
        if cam.faces:
            return self._render_fisheye(cam, pose)
        self._place(cam, pose)
        self._show_only(self._in_view(cam.spec, pose))
        rgb, ids = self._take(cam)
        if not self.description.background:
            rgb[ids == 0] = BLANK_GREY
        fx, fy, cx, cy = intrinsics_of(cam.spec)
        poses = {name: self._poses[name] for name in self._poses if name in self._vehicles}
        return Frame(camera_name, rgb, ids, pose, fx, fy, cx, cy, poses, see_through=frozenset(self._decal_ids))

    def _render_fisheye(self, cam: _Camera, pose: np.ndarray) -> Frame:
        """Each cube face, stacked in an atlas and remapped: colour bilinear, ids nearest; then the view the
        detector gets (raw, or undistorted from the fisheye image, so it pays the fisheye's blur)."""
        rgbs, ids = [], []
        for rot, face in cam.faces:
            face_pose = pose @ rot
            self._place(face, face_pose)
            self._show_only(self._in_view(face.spec, face_pose))
            rgb, face_ids = self._take(face)
            rgbs.append(rgb)
            ids.append(face_ids)
        rgb = cam.cube.remap_colour(cam.cube.atlas(rgbs))
        ids = cam.cube.remap_nearest(cam.cube.atlas(ids))
        lens = cam.lens
        if cam.view is not None:
            lens, map_x, map_y, flat = cam.view
            rgb = remap_bilinear(rgb, map_x, map_y)
            ids = lookup(ids, flat)
        if not self.description.background:
            rgb[ids == 0] = BLANK_GREY
        poses = {name: self._poses[name] for name in self._poses if name in self._vehicles}
        if isinstance(lens, Pinhole):  # a perspective view is a plain pinhole frame
            return Frame(cam.spec.name, rgb, ids, pose, lens.fx, lens.fy, lens.cx, lens.cy, poses,
                         see_through=frozenset(self._decal_ids))
        f = lens.f
        return Frame(cam.spec.name, rgb, ids, pose, f, f, lens.cx, lens.cy, poses, lens=lens,
                     see_through=frozenset(self._decal_ids))

    def unoccluded_ids(self, camera_name: str, names: Iterable[str]) -> dict[str, np.ndarray]:
        """Each named vehicle's unoccluded silhouette (HxW bool) as this camera would see it alone.

        Vehicles whose world bounding boxes project to disjoint image rectangles cannot hide one another, so
        they share one render with everything else hidden; only overlapping ones cost an extra render each.
        Vehicles that project outside the image (first by the frustum test, for all at once) are left out.
        A fisheye camera does this per cube face and remaps each vehicle's faces (nearest neighbour).
        """
        cam = self._camera(camera_name)
        pose = self.camera_pose(camera_name)
        wanted = list(dict.fromkeys(names))
        for name in wanted:
            if name not in self._bodies:
                raise GarageError(f"no entity named {name!r} with its own id", "renderer.unoccluded_ids")
        if not cam.faces:
            return self._silhouettes(cam, pose, wanted)
        per_face = [self._silhouettes(face, pose @ rot, wanted) for rot, face in cam.faces]
        out = {}
        for name in wanted:
            if not any(name in masks for masks in per_face):
                continue
            pictures = [masks.get(name, np.zeros((face.crop[3], face.crop[2]), dtype=bool))
                        for masks, (_, face) in zip(per_face, cam.faces)]
            mask = cam.cube.remap_nearest(cam.cube.atlas(pictures, fill=False), fill=False)
            if cam.view is not None:
                mask = lookup(mask, cam.view[3], fill=False)
            if mask.any():
                out[name] = mask
        return out

    def _silhouettes(self, cam: _Camera, pose: np.ndarray, wanted: list[str]) -> dict[str, np.ndarray]:
        spec = cam.spec
        self._refresh_moved()
        rows = np.array([self._index[name] for name in wanted], dtype=int)
        ahead = ~outside_frustum(frustum_planes(pose, spec), self._lo[rows], self._hi[rows])
        rects = {}
        for name, k, seen in zip(wanted, rows, ahead):
            rect = _image_rect(np.stack([self._lo[k], self._hi[k]]), pose, spec) if seen else None
            if rect is not None:
                rects[name] = rect
        out: dict[str, np.ndarray] = {}
        if not rects:
            return out
        self._place(cam, pose)
        for group in _disjoint_groups(rects):
            alone = np.zeros(len(self._all), dtype=bool)
            alone[[self._index[name] for name in group]] = True
            self._show_only(alone)
            ids = self._take_ids(cam)
            for name in group:
                mask = ids == self._ids[name]
                if mask.any():
                    out[name] = mask
        return out

    # ---- helpers --------------------------------------------------------------------------------------------

    def _camera(self, name: str) -> _Camera:
        if self._scene is None:
            raise GarageError("no scene loaded: call load(scene) first", "renderer")
        cam = self._cameras.get(name)
        if cam is None:
            raise GarageError(f"no camera named {name!r} (have: {', '.join(self._cameras) or 'none'})", "renderer")
        return cam

    def _in_view(self, spec: CameraSpec, pose: np.ndarray) -> np.ndarray:
        """Which bodies this camera's frame draws: the base visibility, less what lies wholly outside the view
        frustum (cull.py) when culling is on. Shadows turn culling off: a body out of view can cast one into it."""
        if not self.cull or self.shadows:
            self.culled = 0
            return self._base
        self._refresh_moved()
        out = outside_frustum(frustum_planes(pose, spec), self._lo, self._hi)
        self.culled = int(np.count_nonzero(out & self._base))
        return self._base & ~out

    def _refresh_moved(self) -> None:
        for name in self._moved:
            k = self._index[name]
            self._lo[k], self._hi[k] = np.asarray(self._all[k].get_global_aabb_fast(), dtype=float)
        self._moved.clear()

    def _show_only(self, mask: np.ndarray) -> None:
        """Set each body's visibility to mask, touching only the bodies that change."""
        for k in np.flatnonzero(mask != self._shown):
            self._all[k].visibility = 1.0 if mask[k] else 0.0
        self._shown = mask.copy()

    def _place(self, cam: _Camera, pose: np.ndarray) -> None:
        import sapien

        cam.component.entity.set_pose(sapien.Pose(pose))
        cam.silhouette.entity.set_pose(sapien.Pose(pose))
        chosen = self.choose_lights(pose[:3, 3])
        for k, light in enumerate(self._pool):
            if k < len(chosen):
                light.pose = sapien.Pose(self._lamp_pos[chosen[k]].tolist())
                light.color = self._lamp_rgb[chosen[k]].tolist()
            else:
                light.color = [0.0, 0.0, 0.0]

    def _take(self, cam: _Camera) -> tuple[np.ndarray, np.ndarray]:
        self._scene.update_render()
        cam.component.take_picture()
        ids = cam.component.get_picture("Segmentation")[..., 1].astype(np.int32)
        rgba = cam.component.get_picture("Color")
        rgb = (np.clip(rgba[..., :3], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        return rgb, ids

    def _take_ids(self, cam: _Camera) -> np.ndarray:
        self._scene.update_render()
        cam.silhouette.take_picture()
        # The minimal shader packs position (mm) and the entity id into one int32 picture.
        return cam.silhouette.get_picture("PositionSegmentation")[..., 3].copy()


def _plain(shape) -> bool:
    """A box drawn in a flat colour (a SAPIEN box whose material can be recoloured in place)."""
    return isinstance(shape, Box) and shape.material.texture is None


def _texture(rm, material: Material) -> None:
    """Give a SAPIEN material its procedural picture (8-bit sRGB with mipmaps: a far floor does not shimmer)."""
    import sapien.render as sr

    from garage_exp.scene.textures import image, srgb8

    rgba, rough = image(material)
    levels = max(1, int(math.log2(min(rgba.shape[:2]))) - 1)
    rm.base_color_texture = sr.RenderTexture2D(np.ascontiguousarray(srgb8(rgba)), "R8G8B8A8Unorm", mipmap_levels=levels, srgb=True)
    if rough is not None:
        rm.roughness_texture = sr.RenderTexture2D(np.ascontiguousarray(rough, dtype=np.float32)[..., None], "R32Sfloat",
                                                  mipmap_levels=levels)


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


def _minimal_shader_dir() -> str:
    import sapien

    return os.path.join(os.path.dirname(sapien.__file__), "vulkan_shader", "minimal")


def _image_rect(aabb: np.ndarray, cam_to_world: np.ndarray, spec: CameraSpec) -> tuple[float, ...] | None:
    """The image rectangle (x1, y1, x2, y2) that a world AABB can cover, or None when it misses the image."""
    lo, hi = np.asarray(aabb, dtype=float)
    local = to_camera(cam_to_world, box_corners(lo, hi))
    if np.all(local[:, 0] <= spec.near):
        return None
    if np.any(local[:, 0] <= spec.near):
        return 0.0, 0.0, float(spec.width), float(spec.height)  # straddles the camera: assume anywhere
    u, v = to_pixels(local, intrinsics_of(spec))
    x1, x2 = max(u.min(), 0.0), min(u.max(), spec.width)
    y1, y2 = max(v.min(), 0.0), min(v.max(), spec.height)
    if x1 >= x2 or y1 >= y2:
        return None
    return x1 - 1.0, y1 - 1.0, x2 + 1.0, y2 + 1.0  # a pixel of margin for rasterisation


def _disjoint_groups(rects: dict[str, tuple[float, ...]]) -> list[list[str]]:
    """Greedy grouping of names whose rectangles do not overlap any other in the same group."""
    groups: list[list[str]] = []
    for name, r in rects.items():
        for group in groups:
            if all(not _overlap(r, rects[other]) for other in group):
                group.append(name)
                break
        else:
            groups.append([name])
    return groups


def _overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def get_renderer(max_lights: int = 8, shadows: bool = False, device: str = "auto") -> SapienRenderer:
    """The process's renderer (created on first call, then reused so shaders compile once per process);
    settings apply from the next `load()`. max_lights: 1-10 (SAPIEN's default shader; render.check_renderer).
    device: auto | cpu | cuda (device.ensure_device; a process keeps the device it first rendered on)."""
    renderer = STATE.renderer
    if not isinstance(renderer, SapienRenderer):
        renderer = STATE.renderer = SapienRenderer(max_lights=max_lights, shadows=shadows, device=device)
    else:
        renderer.max_lights, renderer.shadows, renderer.device = max_lights, shadows, device
    return renderer


def make(*, max_lights: int = 8, shadows: bool = False, save_frames: str = "key", name: str = "sapien",
         device: str = "auto") -> SapienRenderer:
    """The factory `conf/renderer/sapien.yaml` names (`_target_`), called with the `renderer` group's keys:
    the process's renderer with its light pool, shadows and Vulkan device. save_frames and name are the frame
    loop's and the level's, not the renderer's."""
    return get_renderer(max_lights=int(max_lights), shadows=bool(shadows), device=str(device))
