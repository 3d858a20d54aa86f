"""SAPIEN 3 backend: loads a `Scene` description into SAPIEN and renders its cameras.

Registered as the backend `sapien` (`renderer.backend`, the default; render/registry.py), with its own check of
the group (`check_sapien`) and its own batch (render/sapien_batch.py: one RenderSystemGroup under
`renderer.device=cuda`). One renderer per process (`get_renderer()`): the first frame of a process compiles
SAPIEN's shaders (3-7 s measured on lavapipe here) and every later scene reuses them, provided SAPIEN's engine
outlives the scenes (`device.ensure_device` holds it), so a job loads its scene into the existing renderer.

The renderer is made of separate parts, each in its own module:
- `sapien_builder.py`: the SAPIEN entities, shapes and materials of a description (one converter per shape
  type); static structure merged per material and tile; `batch_static=False` keeps an id per structure entity.
- `sapien_cameras.py`: a lit camera and an ids-only twin per camera spec; a fisheye's cube faces.
- `light_pool.py`: the fixed pool of point lights given, frame by frame, to the lamps nearest the camera.
- `bodies.py`: which bodies a frame draws (the blank control, frustum culling, silhouettes' hiding).
- `silhouettes.py`: which vehicles' unoccluded silhouettes can share one render.
This module decides what a load rebuilds (everything, or only the actors and cameras when the statics are
those already loaded) and puts the parts together for a frame.

Blank control (`Scene.background=False`): everything but the vehicles is hidden and empty pixels become
grey 128. This is what "the same vehicle with the background removed" means: the whole vehicle, lit by the
scene's lights, with the garage (pillars included) gone; under the real look the scene's lights are the look's
studio light (`look.blank_light`, scenario/assemble.py), not the preset's. `render.composite.blank_composite`
pastes only given
vehicles' pixels on grey: on a blank render it drops the other vehicles; on a full render it would keep the target cut by its
occluders, which is occlusion without background rather than the control.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from garage_exp.core.errors import GarageError, check_range
from garage_exp.core.state import STATE
from garage_exp.render.base import BLANK_GREY, Frame
from garage_exp.render.bodies import Bodies
from garage_exp.render.cull import frustum_planes, outside_frustum
from garage_exp.render.device import ensure_device
from garage_exp.render.fisheye import lookup, remap_bilinear
from garage_exp.render.icd import check_available
from garage_exp.render.light_pool import LightPool
from garage_exp.render.registry import register_backend
from garage_exp.render.sapien_builder import DECALS, SceneBuilder, is_redrawn, merges, static_key
from garage_exp.render.sapien_batch import open_scene
from garage_exp.render.sapien_cameras import SapienCamera, add_camera, reconfigured, take, take_ids
from garage_exp.render.silhouettes import disjoint_groups, image_rect
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import Material, Pose, Scene


class SapienRenderer:
    """Renders `Scene` descriptions with SAPIEN. Reuse one instance (see `get_renderer`)."""

    def __init__(self, max_lights: int = 8, shadows: bool = False, batch_static: bool = True, cull: bool = True,
                 device: str = "auto"):
        self.device = device  # renderer.device: auto | cpu | cuda (device.ensure_device)
        self.max_lights = max_lights
        self.shadows = shadows
        self.batch_static = batch_static
        self.cull = cull
        # Garages kept loaded (renderer.kept_garages): a load whose statics are those of one of the last N loaded
        # garages takes that SAPIEN scene back and replaces its actors, as a search's trials on one garage do.
        self.kept_garages = 1
        self._kept: list[tuple[tuple, dict]] = []  # the other garages' (statics, loaded state), oldest first
        self._reset()

    def _reset(self) -> None:
        self.description: Scene | None = None
        self._built: SceneBuilder | None = None  # the loaded SAPIEN scene's entities and materials
        self._static: tuple | None = None  # what the loaded static bodies were built from (see load)
        self._restyled = False  # restyle() swapped pictures since the last full load
        self._ego: str | None = None
        self._cameras: dict[str, SapienCamera] = {}
        self._lights = LightPool()
        self.bodies = Bodies()  # what each frame draws

    @property
    def sapien_scene(self):
        """The loaded sapien.Scene (None before a load)."""
        return self._built.scene if self._built is not None else None

    @property
    def culled(self) -> int:
        """Bodies the last render hid as outside the frustum."""
        return self.bodies.culled

    # ---- loading --------------------------------------------------------------------------------------------

    def load(self, scene: Scene) -> None:
        """(Re)build the SAPIEN scene from a description; cameras, lights and ids are replaced. When the static
        structure, lamps and settings are those already loaded (the trials of a search, which change only the
        actors), only the actors and cameras are replaced: the merged static bodies stay."""
        ensure_device(self.device)
        import sapien

        static = self._static_key(scene)
        if self._built is not None and self.kept_garages > 1 and self._recolouring(static) is None:
            self._switch(static)
        # A restyled scene (a replicate's pictures) no longer shows its description's materials: rebuild it.
        recolour = self._recolouring(static) if self._built is not None and not self._restyled else None
        if recolour is not None:
            change, redraw = recolour
            try:
                self._built.recolour(change)
                if redraw:  # the lines' wear, the failed lamps: those bodies alone are rebuilt
                    self._built.replace_redrawn(e for e in scene.entities
                                                if merges(e, self.batch_static) and is_redrawn(e))
                self._replace_actors(scene)
            except BaseException:
                self._reset()
                raise
            self.description, self._static = scene, static
            return
        self._reset()
        try:
            built = SceneBuilder(sapien.Scene())
        except RuntimeError as exc:
            raise GarageError(f"SAPIEN could not create a scene ({exc})", "renderer") from exc
        try:
            self._build(built, scene)
        except BaseException:
            self._reset()  # never leave a half-built scene to render
            raise
        self._built = built
        self.description = scene
        self._static = static

    # What one loaded garage is: the SAPIEN scene and what this renderer holds of it (swapped by _switch).
    LOADED = ("description", "_built", "_static", "_restyled", "_ego", "_cameras", "_lights", "bodies")

    def _switch(self, static: tuple) -> None:
        """Another garage: keep the loaded one (unless restyled) among the last `kept_garages - 1` others and take
        back the kept one with these statics' geometry, if any (its materials recoloured and actors replaced by
        the load, as with a garage never left); else start empty for a full load. The least recently used
        garage beyond the limit is dropped (its SAPIEN scene freed)."""
        def garage(key: tuple) -> tuple:
            return (key[0], *key[3:])  # the geometry and settings: materials recoloured, line paint rebuilt

        if not self._restyled:
            self._kept.append((garage(self._static), {name: getattr(self, name) for name in self.LOADED}))
        wanted = garage(static)
        back = next((k for k, (key, _) in enumerate(self._kept) if key == wanted), None)
        held = self._kept.pop(back)[1] if back is not None else None
        del self._kept[:max(0, len(self._kept) - (self.kept_garages - 1))]  # the least recently used go
        self._reset()
        for name, value in (held or {}).items():
            setattr(self, name, value)

    def _static_key(self, scene: Scene) -> tuple:
        """What the merged static bodies are made of (sapien_builder.static_key): all but line paint and lamps,
        their (geometry, materials) apart (sapien_builder.is_redrawn), and the settings. Lamps and ambient light
        are set on every load."""
        merged = [e for e in scene.entities if merges(e, self.batch_static)]
        geometry, materials = static_key(e for e in merged if not is_redrawn(e))
        redrawn = static_key(e for e in merged if is_redrawn(e))
        return (geometry, materials, redrawn, scene.background, self.max_lights, self.shadows, self.batch_static)

    def _recolouring(self, static: tuple) -> tuple[dict[Material, Material], bool] | None:
        """How the loaded statics become the new ones without a full load: (the old -> new material map, whether
        line paint and lamps are rebuilt), or None (a full load). When all the statics are the loaded ones with
        other materials (a search's light intensity changes the lamp panels' glow; a wide space's draw the
        floor's wetness and grime: their pictures), all are recoloured. A map fails when one old material would
        need two new ones (lamps switched on or off: the merge groups shapes by material) or two old ones one new
        (a full load would merge their bodies). Else, when only line paint and lamps differ beyond their colours
        (a wide space's wear and failed lamps), the rest is recoloured and they are rebuilt, provided no other
        static shape shares a material with them, in the loaded scene or the new one."""
        old = self._static
        if old is None or static[0] != old[0] or static[3:] != old[3:]:
            return None
        if static[2][0] == old[2][0]:
            change = _material_map([*old[1], *old[2][1]], [*static[1], *static[2][1]])
            if change is not None:
                return change, False
        if not (_redrawn_apart(static) and _redrawn_apart(old)):
            return None
        change = _material_map(old[1], static[1])
        return None if change is None else (change, True)

    def restyle(self, change: dict[Material, Material]) -> None:
        """Give loaded textured materials other pictures (a replicate's stains and wetness): the shapes keep
        their SAPIEN materials, whose textures are replaced; nothing is rebuilt."""
        self._restyled = self._restyled or bool(change)
        if self._built is not None:
            self._built.restyle(change)

    def _build(self, built: SceneBuilder, scene: Scene) -> None:
        built.scene.set_ambient_light([float(c) for c in scene.ambient])
        built.add_statics(e for e in scene.entities if merges(e, self.batch_static))
        # The actors after the statics, as _replace_actors adds them to a scene it keeps: SAPIEN draws bodies in
        # the order they were added, and where an actor's contact shadow meets a pillar's (both decals at
        # SHADOW_Z, blended) the later one is drawn over the other. Any other order gave a search's trials
        # (statics kept) other pixels than the same job loaded fresh (issue 31, item 3).
        self._add_actors(built, scene)
        self._mount_cameras(built, scene)
        self._lights.set_lamps(scene)
        self._lights.add_to(built.scene, self.max_lights, self.shadows)
        self._index_bodies(built, scene)

    def _replace_actors(self, scene: Scene) -> None:
        """Remove every entity with its own id and every camera, add the new scene's; the merged statics and
        the light pool stay (shown again in full: the last frame may have culled some)."""
        built = self._built
        built.remove_actors()
        # A camera of the same name and size is set to its new spec in place (sapien_cameras.reconfigured).
        specs = {spec.name: spec for spec in scene.cameras}
        kept: dict[str, SapienCamera] = {}
        for name, cam in self._cameras.items():
            again = reconfigured(cam, specs[name]) if name in specs else None
            if again is not None:
                kept[name] = again
                continue
            for pinhole in cam.pinholes():  # a fisheye's cube faces are cameras of their own
                built.scene.remove_entity(pinhole.component.entity)
                built.scene.remove_entity(pinhole.silhouette.entity)
        self._cameras = {}
        for body in built.merged:
            body.visibility = 1.0
        built.scene.set_ambient_light([float(c) for c in scene.ambient])
        self._lights.set_lamps(scene)
        self._add_actors(built, scene)
        self._mount_cameras(built, scene, kept)
        self._index_bodies(built, scene)

    def _add_actors(self, built: SceneBuilder, scene: Scene) -> None:
        for entity in scene.entities:
            if not merges(entity, self.batch_static):
                built.add_entity(entity)

    def _mount_cameras(self, built: SceneBuilder, scene: Scene, kept: dict[str, SapienCamera] | None = None) -> None:
        """The scene's cameras: each a new one, or the one `kept` under its name (already set to its spec)."""
        egos = [e.name for e in scene.entities if e.role == "ego"]
        self._ego = egos[0] if egos else None
        if scene.cameras and self._ego is None:
            raise GarageError("the scene has cameras but no entity with role 'ego' to mount them on", scene.name)
        for spec in scene.cameras:
            if spec.name in self._cameras:
                raise GarageError(f"two cameras are named {spec.name!r}", "scene.cameras")
            self._cameras[spec.name] = (kept or {}).get(spec.name) or add_camera(built.scene, spec)

    def _index_bodies(self, built: SceneBuilder, scene: Scene) -> None:
        # The blank control: everything but the vehicles is hidden (also from the silhouette renders).
        base = ([scene.background or name in built.vehicles for name in built.bodies]
                + [scene.background] * len(built.merged))
        self.bodies = Bodies(built.bodies, built.merged, base, built.merged_boxes())

    # ---- per frame ------------------------------------------------------------------------------------------

    @property
    def ids(self) -> dict[str, int]:
        """Entity name -> segmentation id (`per_scene_id`) for every entity with its own id."""
        return dict(self._built.ids) if self._built is not None else {}

    @property
    def poses(self) -> dict[str, Pose]:
        return dict(self._built.poses) if self._built is not None else {}

    def set_pose(self, name: str, pose: Pose) -> None:
        """Move an entity that has its own id (vehicles, the ego: the cameras follow the ego)."""
        if self._built is None:
            raise GarageError(f"no movable entity named {name!r} in the loaded scene", "renderer.set_pose")
        self.bodies.moved.update(self._built.set_pose(name, pose))

    def camera_pose(self, camera_name: str) -> np.ndarray:
        return camera_to_world(self._built.poses[self._ego], self._camera(camera_name).spec)

    def choose_lights(self, position: Sequence[float]) -> np.ndarray:
        """Indices of the lamps that get the pool's lights at this camera position (largest intensity/d^2)."""
        return self._lights.choose(position, self.max_lights)

    def render(self, camera_name: str) -> Frame:
        """Render one camera: colour and entity ids, with the camera's pose and intrinsics."""
        cam = self._camera(camera_name)
        pose = self.camera_pose(camera_name)
        if cam.faces:
            return self._render_fisheye(cam, pose)
        self._place(cam, pose)
        self.bodies.show_only(self._in_view(cam, pose))
        rgb, ids = take(self._built.scene, cam)
        if not self.description.background:
            rgb[ids == 0] = BLANK_GREY
        return Frame(camera_name, rgb, ids, pose, lens_of(cam.spec), self._vehicle_poses(),
                     see_through=frozenset(self._built.decal_ids), pillars=self.pillar_ids)

    def _render_fisheye(self, cam: SapienCamera, pose: np.ndarray) -> Frame:
        """Each cube face, stacked in an atlas and remapped: colour bilinear, ids nearest; then the view the
        detector gets (raw, or undistorted from the fisheye image, so it pays the fisheye's blur)."""
        rgbs, ids = [], []
        for rot, face in cam.faces:
            face_pose = pose @ rot
            self._place(face, face_pose)
            self.bodies.show_only(self._in_view(face, face_pose))
            rgb, face_ids = take(self._built.scene, face)
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
        return Frame(cam.spec.name, rgb, ids, pose, lens, self._vehicle_poses(),
                     see_through=frozenset(self._built.decal_ids), pillars=self.pillar_ids)

    def unoccluded_ids(self, camera_name: str, names: Iterable[str]) -> dict[str, np.ndarray]:
        """Each named vehicle's unoccluded silhouette (HxW bool) as this camera would see it alone.

        Vehicles whose world bounding boxes project to disjoint image rectangles share one render with
        everything else hidden (silhouettes.py); only overlapping ones cost an extra render each. Vehicles that
        project outside the image (first by the frustum test, for all at once) are left out. A fisheye camera
        does this per cube face and remaps each vehicle's faces (nearest neighbour).
        """
        cam = self._camera(camera_name)
        pose = self.camera_pose(camera_name)
        wanted = list(dict.fromkeys(names))
        for name in wanted:
            if name not in self._built.bodies:
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

    def _silhouettes(self, cam: SapienCamera, pose: np.ndarray, wanted: list[str]) -> dict[str, np.ndarray]:
        spec, bodies = cam.spec, self.bodies
        bodies.refresh_moved()
        rows = np.array([bodies.index[name] for name in wanted], dtype=int)
        ahead = ~outside_frustum(frustum_planes(pose, spec), bodies.lo[rows], bodies.hi[rows])
        rects = {}
        for name, k, seen in zip(wanted, rows, ahead):
            rect = image_rect(np.stack([bodies.lo[k], bodies.hi[k]]), pose, spec) if seen else None
            if rect is not None:
                rects[name] = rect
        out: dict[str, np.ndarray] = {}
        if not rects:
            return out
        self._place(cam, pose)
        # The groups differ only by which bodies show: the render scene's poses are synced once, for the first
        # (about 8 groups in a dense garage's frame; each sync walks every entity).
        for k, group in enumerate(disjoint_groups(rects)):
            bodies.show_only(bodies.only(group))
            ids = take_ids(self._built.scene, cam, sync=k == 0)
            for name in group:
                mask = ids == self._built.ids[name]
                if mask.any():
                    out[name] = mask
        return out

    # ---- what the batched scene (render/batch.py) reads and sets -------------------------------------------

    def sibling(self, cull: bool | None = None) -> "SapienRenderer":
        """A new renderer with these settings: another sub-scene of a `render.batch.RenderScene` (the shaders
        are compiled once per process, so it costs only its scene's build)."""
        return SapienRenderer(max_lights=self.max_lights, shadows=self.shadows, batch_static=self.batch_static,
                              cull=self.cull if cull is None else cull, device=self.device)

    @property
    def ego(self) -> str | None:
        """The loaded scene's ego entity (the cameras' carrier)."""
        return self._ego

    @property
    def movers(self) -> list[str]:
        """Entities that move from shot to shot with their own render shapes: every one with its own id but the
        ego and the decal holders (which move with their actor, `render_shapes`)."""
        return [n for n in self._built.entities if n != self._ego and not n.endswith(DECALS)]

    @property
    def vehicles(self) -> set[str]:
        return set(self._built.vehicles)

    @property
    def decal_ids(self) -> frozenset[int]:
        """Ids of flat pictures on the floor that hide nothing (`Frame.see_through`)."""
        return frozenset(self._built.decal_ids)

    @property
    def pillar_ids(self) -> frozenset[int]:
        """Ids of the structure's pillars (`Frame.pillars`)."""
        return frozenset(self._built.pillar_ids)

    def render_shapes(self, name: str) -> list:
        """The SAPIEN render shapes of entity `name` and of its decals (its contact shadow), which move with it."""
        entities = self._built.entities
        return [shape for node in (entities.get(name), entities.get(name + DECALS)) if node is not None
                for body in node.components for shape in getattr(body, "render_shapes", [])]

    def camera_components(self, camera_name: str) -> tuple[object, object]:
        """A pinhole camera's SAPIEN components: the lit one and its ids-only twin."""
        cam = self._camera(camera_name)
        return cam.component, cam.silhouette

    def place_camera(self, camera_name: str, pose: np.ndarray) -> None:
        """The camera at a 4x4 pose, and the light pool on the lamps nearest it."""
        self._place(self._camera(camera_name), pose)

    def show(self, names: Sequence[str] | None = None) -> None:
        """Draw what a frame draws (None: the scene's base visibility, not culled), or only the named entities."""
        self.bodies.show_only(self.bodies.base if names is None else self.bodies.only(list(names)))

    # ---- helpers --------------------------------------------------------------------------------------------

    def _camera(self, name: str) -> SapienCamera:
        if self._built is None:
            raise GarageError("no scene loaded: call load(scene) first", "renderer")
        cam = self._cameras.get(name)
        if cam is None:
            raise GarageError(f"no camera named {name!r} (have: {', '.join(self._cameras) or 'none'})", "renderer")
        return cam

    def _in_view(self, cam: SapienCamera, pose: np.ndarray) -> np.ndarray:
        # Shadows turn culling off: a body out of view can cast one into it.
        return self.bodies.in_view(cam.spec, pose, self.cull and not self.shadows)

    def _place(self, cam: SapienCamera, pose: np.ndarray) -> None:
        """The camera at its pose, and the pool's lights on the lamps that matter there."""
        cam.place(pose)
        self._lights.place(pose[:3, 3], self.max_lights)

    def _vehicle_poses(self) -> dict[str, Pose]:
        poses = self._built.poses
        return {name: poses[name] for name in poses if name in self._built.vehicles}


def _redrawn_apart(key: tuple) -> bool:
    """Whether a static key's line paint and lamps (`_static_key`) have materials of their own: no other merged
    shape's."""
    return not set(key[2][1]) & set(key[1])


def _material_map(old: list[Material], new: list[Material]) -> dict[Material, Material] | None:
    """The old -> new map that turns each old material into the new one in its place; None when one old material
    would need two new ones, or two old ones one new."""
    change: dict[Material, Material] = {}
    for before, after in zip(old, new):
        if change.setdefault(before, after) != after:
            return None
    return change if len(set(change.values())) == len(change) else None


def get_renderer(max_lights: int = 8, shadows: bool = False, device: str = "auto") -> SapienRenderer:
    """The process's renderer (created on first call, then reused so shaders compile once per process);
    settings apply from the next `load()`. max_lights: 1-10 (SAPIEN's default shader; render.open.check_renderer).
    device: auto | cpu | cuda (device.ensure_device; a process keeps the device it first rendered on)."""
    renderer = STATE.renderer
    if not isinstance(renderer, SapienRenderer):
        renderer = STATE.renderer = SapienRenderer(max_lights=max_lights, shadows=shadows, device=device)
    else:
        renderer.max_lights, renderer.shadows, renderer.device = max_lights, shadows, device
    return renderer


MAX_KEPT = 16  # loaded garages kept (renderer.kept_garages): each holds its SAPIEN scene's memory


def check_sapien(conf) -> None:
    """The `renderer` group's keys that are SAPIEN's: a light pool its default shader can compile (1-10), 1 to
    MAX_KEPT kept garages, a device (auto | cpu | cuda) whose Vulkan driver's files are there (whether Vulkan
    really finds the device shows when the first scene loads, `ensure_device`)."""
    check_range(conf.max_lights, 1, 10, "renderer.max_lights")
    check_range(conf.get("kept_garages", 1), 1, MAX_KEPT, "renderer.kept_garages")
    check_available(conf.device)


@register_backend("sapien", scene=open_scene, check=check_sapien,
                  says="SAPIEN 3: RGB and segmentation on Vulkan; a RenderSystemGroup under renderer.device=cuda")
def make(*, max_lights: int = 8, shadows: bool = False, save_frames: str = "key", name: str = "sapien",
         device: str = "auto", kept_garages: int = 1) -> SapienRenderer:
    """The backend's factory (`render.open.open_renderer` calls it with the `renderer` group's keys): the process's
    renderer with its light pool, shadows, Vulkan device and kept garages. save_frames and name are the frame
    loop's and the level's, not the renderer's."""
    renderer = get_renderer(max_lights=int(max_lights), shadows=bool(shadows), device=str(device))
    renderer.kept_garages = int(kept_garages)
    return renderer
