"""The scene's config nodes (the garage, the light, the camera rig and its bird's-eye view, the palette, the look,
materials and clutter), beside the code that builds and checks them in this package (scene/structure.py,
lamps.py, camera.py, parking.py, look.py, clutter.py), registered as config nodes here (core/config_nodes.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from garage_exp.core.config_nodes import register_node
from garage_exp.scene.description import Pose


@dataclass
class GarageConf:
    """Geometry and materials of the built garage (not swept by default)."""

    ceiling_height: float = 2.8
    slab_thickness: float = 0.3
    pillar_size: float = 0.6  # square pillars, metres per side
    wall_thickness: float = 0.25
    bay_width: float = 2.5  # a cell wider than this along its lane holds several bays
    lamp_spacing: float = 5.0  # lamps on a regular grid over driveable cells and bays, metres
    lamp_size: tuple[float, float] = (1.2, 0.2)
    marking_width: float = 0.12
    marking_wear: float = 0.0  # 0 fresh paint .. 1 invisible


@dataclass
class LightConf:
    """A lighting preset: which lamps are on and how bright. Off lamps keep their light at intensity 0 so
    the renderer's light count (and SAPIEN's compiled shaders) never change."""

    name: str = "bright"
    coverage: float = 1.0  # fraction of lamps on
    intensity: float = 1.0  # per-lamp point-light strength (renderer units; 1.0 ~ a 40 W LED batten)
    ambient: float = 0.05  # uniform ambient light (0..1)
    colour: tuple[float, float, float] = (1.0, 0.96, 0.9)
    seed: int = 0  # which lamps are off when coverage < 1
    # The lamps' correlated colour temperature (K, 1000-12000); None: `colour` as written. Set, it replaces
    # `colour` (scene/lamps.py: lamp_colour): LED garage lamps 4000-5000 K, old sodium lamps about 2000 K.
    temperature: Optional[float] = None


@dataclass
class CameraConf:
    """One camera on the ego: mount relative to the ego's origin (centre of its footprint, on the floor),
    x forward, y left, z up; yaw left-positive; pitch positive looks down. fovy is the VERTICAL field of
    view in degrees (Unity's and SAPIEN's convention). `mount` names a pose on the ego's body
    (garage_exp/scene/camera.py MOUNTS, scaled by the ego's extent) that replaces x, y, z and yaw.
    `model: fisheye` is OpenCV's fisheye (Kannala-Brandt) lens: `fov` is its full field of view across the
    image width, `k` its four coefficients; fovy is then unused."""

    name: str = "front"
    x: float = 0.5
    y: float = 0.0
    z: float = 1.55
    yaw: float = 0.0
    pitch: float = 0.0
    fovy: float = 60.0
    width: int = 640
    height: int = 480
    mount: Optional[str] = None
    model: str = "pinhole"  # pinhole | fisheye
    fov: float = 190.0  # fisheye only: degrees across the image width (the image circle spans the width)
    k: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])  # fisheye only: k1..k4


@dataclass(unsafe_hash=True)
class BevSpec:
    """A bird's-eye view stitched from the rig's fisheyes (garage_exp/render/bev.py): `length` metres along the
    ego's forward axis, `width` across, centred on the ego, at `meters_per_pixel`. 18 m across holds the 5 m deep
    bays on both sides of a 6 m lane whole (their back corners 8 m from the lane's centre).

    One class for the `camera.bev` node and the extent the BEV's code works with (render/bev.py: spec_of types a
    node as it; orientation and pixels as render/bev.py says). Equal and hashed by its extent (`enabled` aside),
    so that the maps cached per spec (bev_maps) are shared; not frozen, so that overrides can set a node's keys."""

    # Write the BEV on any fisheye rig; a case with `slots: true` turns it on by itself. Keyword-only, so that
    # BevSpec(length, width, meters_per_pixel) is the extent.
    enabled: bool = field(default=False, kw_only=True, compare=False)
    length: float = 12.0
    width: float = 18.0
    meters_per_pixel: float = 0.03

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return (int(round(self.width / self.meters_per_pixel)), int(round(self.length / self.meters_per_pixel)))

    def ego_to_pixel(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Points in the ego's frame (forward, left; metres) -> continuous BEV pixel coordinates (col, row)."""
        w, h = self.size
        return (w / 2.0 - np.asarray(y, float) / self.meters_per_pixel,
                h / 2.0 - np.asarray(x, float) / self.meters_per_pixel)

    def pixel_to_ego(self, col, row) -> tuple[np.ndarray, np.ndarray]:
        w, h = self.size
        return ((h / 2.0 - np.asarray(row, float)) * self.meters_per_pixel,
                (w / 2.0 - np.asarray(col, float)) * self.meters_per_pixel)

    def world_to_pixel(self, ego: Pose, points) -> np.ndarray:
        """World points (N x 2 or N x 3; z ignored) -> BEV pixels (N x 2) for an ego standing at `ego`."""
        p = np.asarray(points, float).reshape(-1, np.asarray(points).shape[-1])[:, :2]
        c, s = math.cos(math.radians(ego.yaw)), math.sin(math.radians(ego.yaw))
        dx, dy = p[:, 0] - ego.x, p[:, 1] - ego.y
        u, v = self.ego_to_pixel(c * dx + s * dy, -s * dx + c * dy)
        return np.stack([u, v], axis=1)

    def world_direction(self, ego: Pose, yaw: float) -> float:
        """A world heading (degrees) as a direction in the BEV image, radians atan2(d_row, d_col)."""
        rel = math.radians(yaw - ego.yaw)
        return math.atan2(-math.cos(rel), -math.sin(rel))


@dataclass
class CameraRigConf:
    """A rig of cameras. The top-level keys are factors a sweep or a search varies with plain overrides
    (`camera.mount=mirror camera.fovy=90`); None leaves the camera's own value. mount, fovy, pitch and z apply
    to a one-camera rig only; width and height to every camera; `view` to fisheye cameras."""

    name: str = "front"
    cameras: list[CameraConf] = field(default_factory=lambda: [CameraConf()])
    roof: bool = True  # z is added to the ego vehicle's height (camera on the roof); unused by named mounts
    mount: Optional[str] = None
    fovy: Optional[float] = None
    pitch: Optional[float] = None
    z: Optional[float] = None  # metres added to the camera's height (a named mount's or the list's)
    width: Optional[int] = None
    height: Optional[int] = None
    view: str = "raw"  # fisheye frames go to the detector raw, or undistorted: perspective | cylindrical
    bev: BevSpec = field(default_factory=BevSpec)  # a bird's-eye view from the rig's fisheyes (render/bev.py)


@dataclass
class PaletteConf:
    """Which vehicle models and colours fill the garage."""

    name: str = "default"
    ego: str = "tcamrysilver"
    target_colours: list[str] = field(default_factory=lambda: ["black", "white"])
    target: str = ""  # one model for every colour; empty: target_models, else a medium car of each colour
    target_models: dict[str, str] = field(default_factory=dict)  # colour -> model name
    parked_occupancy: float = 0.0  # fraction of free bays with a parked car
    parked_classes: list[str] = field(default_factory=lambda: ["small", "medium"])
    models: list[str] = field(default_factory=list)  # allowed models; empty: all that fit under the ceiling
    seed: int = 0


@dataclass
class LookConf:
    """How real the world looks (conf/look): `real` picks textured materials, clutter and the real camera (its
    defaults list) and adds contact shadows; `flat` is the renderer's output before the real look."""

    name: str = "real"
    contact_shadows: bool = True  # soft decals under vehicles, people, pillars and along walls
    # metres each lamp's point light hangs below its panel: a fixture's reflector sends its light down, so the
    # ceiling above it is not a blown-out disc (0: the light just under the panel, as the flat look has it)
    fixture_drop: float = 0.0
    # The blank control's light (the vehicle alone on grey): a preset of its own that no `light` changes, as the
    # research's clean, evenly lit render of the car; None: the job's light preset (the flat look's blank).
    blank_light: Optional[LightConf] = None


@dataclass
class MaterialsConf:
    """Procedural surfaces (conf/materials; garage_exp/scene/look.py)."""

    name: str = "none"
    level: str = "none"  # none | clean | worn | wet | random
    grime: Optional[float] = None  # 0-1: override the level's stains and dirt
    wetness: Optional[float] = None  # 0-1: override the level's puddles
    seed: int = 0  # added to the job's seed: which stains, cracks and (random level) which garage


@dataclass
class ClutterConf:
    """Ducts, pipes, signs, wheel stops, bollards, floor arrows (conf/clutter; garage_exp/scene/clutter.py)."""

    name: str = "none"
    level: str = "none"  # none | typical | dense


register_node("garage", GarageConf, group=True)
register_node("light", LightConf, group=True)
register_node("camera", CameraRigConf, group=True)
register_node("palette", PaletteConf, group=True)
register_node("look", LookConf, group=True)
register_node("materials", MaterialsConf, group=True)
register_node("clutter", ClutterConf, group=True)
