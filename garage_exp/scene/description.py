"""A plain-data description of a garage scene, between the plan and any renderer.

Nothing here imports SAPIEN or trimesh: geometry is testable and exportable without a GPU.
Frame: Z up, metres; yaw in degrees counter-clockwise from +x (see DEVELOPERS.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from garage_exp.scene.lenses import camera_model

Role = Literal["structure", "marking", "lamp", "parked", "target", "occluder", "ego", "moving"]
# Roles of actors (vehicles, people, box occluders): each has its own id and pose; vehicles and people get ground
# truth. The name is older than the people; `Entity.kind` tells them apart.
VEHICLE_ROLES = ("parked", "target", "occluder", "ego", "moving")
ACTOR_ROLES = VEHICLE_ROLES
PILLAR_PREFIX = "pillar_"  # the structure's pillars are named pillar_<a>_<b> (scene/structure.py)


@dataclass(frozen=True)
class Pose:
    """Position and heading. Roll and pitch are never needed for a garage's rigid objects."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0  # degrees, CCW from +x

    def compose(self, local: "Pose") -> "Pose":
        """This pose applied to `local` (local expressed in this pose's frame)."""
        c, s = math.cos(math.radians(self.yaw)), math.sin(math.radians(self.yaw))
        return Pose(
            self.x + c * local.x - s * local.y,
            self.y + s * local.x + c * local.y,
            self.z + local.z,
            (self.yaw + local.yaw) % 360.0,
        )


@dataclass(frozen=True)
class Texture:
    """A procedural texture: plain data that `garage_exp.scene.textures.image` turns into pixels, the same for
    every renderer and for the glTF export. A box's texture is mapped by world position, `tile` metres per
    repeat, so neighbouring boxes join without seams; a decal's spans the decal once.

    kind: what it draws (textures.KINDS: concrete, asphalt, wall, stripes, paint, ceiling, sign, shadow...).
    seed: which stains, cracks and marks. params: (name, value) pairs the kind reads (grime, wetness, wear...).
    """

    kind: str
    seed: int = 0
    tile: float = 4.0
    params: tuple[tuple[str, float | str], ...] = ()

    def param(self, name: str, default: float | str = 0.0) -> float | str:
        return dict(self.params).get(name, default)


@dataclass(frozen=True)
class Material:
    name: str
    color: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 1.0)  # linear RGBA
    roughness: float = 0.8
    metallic: float = 0.0
    emission: tuple[float, float, float] = (0.0, 0.0, 0.0)  # emissive panels (lamps)
    # A picture instead of the flat colour (its pixels already hold `color`); None: today's flat colour.
    texture: Texture | None = None
    # Specular reflectance of a dielectric, SAPIEN's convention (0.5: F0 = 0.04, paint, concrete, epoxy). The
    # flat look's surfaces have none: no highlights at all, which is part of why it looks flat.
    specular: float = 0.0


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in its entity's frame: `size` is the full extent (x, y, z)."""

    size: tuple[float, float, float]
    material: Material
    offset: Pose = Pose()


@dataclass(frozen=True)
class Mesh:
    """A mesh file (GLB, Z up, metres, recentred: wheels at z=0, nose along +x)."""

    path: str
    offset: Pose = Pose()
    scale: float = 1.0
    # A vehicle's paint, linear RGB: the body's colour multiplied into its materials (renderers: the base colour
    # factor over the model's textures); None: the model's own paint.
    paint: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Decal:
    """A flat, alpha-blended picture `size` (x, y) metres on the floor: contact shadows, floor arrows, stains.
    It belongs to its entity (a shadow moves with its car) but carries no id of the entity's: renderers draw
    it as a separate body, so ground truth never counts its pixels as the actor's."""

    size: tuple[float, float]
    material: Material
    offset: Pose = Pose()


Shape = Box | Mesh | Decal


@dataclass
class Entity:
    """A named object. Renderers give each entity its own segmentation id."""

    name: str
    role: Role
    pose: Pose
    shapes: list[Shape] = field(default_factory=list)
    # Actors: the model name, its size class and its extent (length, width, height; a person faces +x).
    model: str | None = None
    size_class: str | None = None
    extent: tuple[float, float, float] | None = None
    static: bool = True
    # An actor's kind: "vehicle" | "person" | "box" (a static occluder); None for structure, markings and lamps
    # (and for a vehicle built before kinds existed: an actor without a kind is a vehicle).
    kind: str | None = None

    @property
    def is_person(self) -> bool:
        return self.kind == "person"

    @property
    def is_pillar(self) -> bool:
        """One of the structure's pillars (what ground truth names an occluder `pillar`)."""
        return self.role == "structure" and self.name.startswith(PILLAR_PREFIX)


@dataclass(frozen=True)
class Light:
    """A point light. `intensity` 0 keeps the light in the scene (no shader recompile) but dark."""

    name: str
    position: tuple[float, float, float]
    color: tuple[float, float, float] = (1.0, 0.95, 0.85)
    intensity: float = 1.0


@dataclass(frozen=True)
class CameraSpec:
    """A camera mounted on the ego: `mount` is relative to the ego's pose; fovy is the vertical FOV."""

    name: str
    mount: Pose
    pitch: float = 0.0  # degrees, positive looks down
    fovy: float = 60.0
    width: int = 640
    height: int = 480
    near: float = 0.05
    far: float = 100.0
    # The camera model: its lens class (scene/lenses; `scene.lenses.lens_of(spec)` is the lens). A fisheye camera
    # (model "fisheye"): OpenCV's Kannala-Brandt lens with coefficients k and `fov` degrees across the image width,
    # rendered from a cube map (render/fisheye.py); fovy is unused. `view` is what the detector gets: the raw
    # fisheye image, or a perspective / cylindrical view undistorted from it (scene/views.py).
    model: str = "pinhole"
    fov: float = 0.0
    k: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    view: str = "raw"

    @property
    def fisheye(self) -> bool:
        """Drawn from a cube map through its model's lens (scene/lenses; every lens but a perspective one)."""
        return not camera_model(self.model).perspective


@dataclass
class Scene:
    name: str
    entities: list[Entity] = field(default_factory=list)
    lights: list[Light] = field(default_factory=list)
    ambient: tuple[float, float, float] = (0.05, 0.05, 0.05)
    cameras: list[CameraSpec] = field(default_factory=list)
    # Bounds of the garage footprint: (xmin, ymin, xmax, ymax) and the ceiling height.
    bounds: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    ceiling: float = 2.8
    background: bool = True  # False: the blank control (only vehicles are drawn)

    def entity(self, name: str) -> Entity:
        for e in self.entities:
            if e.name == name:
                return e
        raise KeyError(name)

    def by_role(self, *roles: str) -> list[Entity]:
        return [e for e in self.entities if e.role in roles]

    def actors(self) -> list[Entity]:
        """Vehicles, people and box occluders (the entities with an actor's role)."""
        return self.by_role(*ACTOR_ROLES)

    def vehicles(self) -> list[Entity]:
        return [e for e in self.actors() if e.kind not in ("person", "box")]

    def people(self) -> list[Entity]:
        return [e for e in self.actors() if e.is_person]
