"""Structured configs: the schemas every layer shares and the registration of the rest, in Hydra's ConfigStore.

A YAML level of a group is validated against its dataclass (typos and wrong types fail at compose time). The
groups of the frame path that several layers read live here; a node that one layer above core owns (`search`,
`ego`, `slot_detector`, `export`) is declared beside its check in that layer and registered here by dotted name (NODES,
GROUPS), so that core imports no layer above it. `Config` is the top-level dataclass they make (config_schema).
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from garage_exp.core.state import STATE


@dataclass
class PlanGeneratorConf:
    """`plan=generated`: what the seeded garage generator (garage_exp/plan/generator.py) draws from. A range is
    [lo, hi] (or one value); an integer range includes both ends; `family` is one layout family or a list to draw
    from. Checked by garage_exp.plan.generator.generator_settings; ranges and their sources in docs/plans.md."""

    family: Any = "loop"  # loop | comb | grid | spine, or a list of them
    aisles: Any = field(default_factory=lambda: [2, 3])  # east-west lanes: 3 cells north-south each
    spans: Any = field(default_factory=lambda: [4, 7])  # bay cells along an aisle (pillar to pillar)
    bays_per_span: Any = field(default_factory=lambda: [2, 3])  # bays between two pillars along an aisle
    bay_width: Any = field(default_factory=lambda: [2.3, 2.7])  # m; bays beside a pillar get 2.40 m clear
    bay_depth: Any = field(default_factory=lambda: [5.1, 5.5])  # m (the ordinance: >= 5.0)
    lane_width: Any = field(default_factory=lambda: [5.6, 6.5])  # m; at least the ordinance's for the bay width
    pillar_size: Any = field(default_factory=lambda: [0.4, 0.9])  # m, square section
    ceiling_height: Any = field(default_factory=lambda: [2.5, 3.2])  # m; null: garage.ceiling_height
    ramps: Any = field(default_factory=lambda: [1, 2])  # 1: one two-way ramp; 2: an entrance and an exit
    cores: Any = field(default_factory=lambda: [0, 2])  # stair and lift cores in the islands
    wall_bays: Any = 0.8  # chance that a side of the garage has bays along its wall (else a bare wall)


@dataclass
class PlanConf:
    name: str = "research"
    file: Optional[str] = None  # any plan file; overrides `name` (shipped plans live in plans/NAME.yaml)
    seed: Optional[int] = None  # plan=generated: which draw of the generator
    generator: Optional[PlanGeneratorConf] = None  # plan=generated: the generator's ranges (conf/plan/generated.yaml)


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


@dataclass
class BevConf:
    """A bird's-eye view stitched from the rig's fisheyes (garage_exp/render/bev.py): `length` metres along the
    ego's forward axis, `width` across, centred on the ego, at `meters_per_pixel`. 18 m across holds the 5 m deep
    bays on both sides of a 6 m lane whole (their back corners 8 m from the lane's centre)."""

    enabled: bool = False  # write the BEV on any fisheye rig; a case with `slots: true` turns it on by itself
    length: float = 12.0
    width: float = 18.0
    meters_per_pixel: float = 0.03


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
    bev: BevConf = field(default_factory=BevConf)  # a bird's-eye view from the rig's fisheyes (render/bev.py)


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
class ActorConf:
    """One actor of a scenario. Every value is a plain key (`case.actors.target.offset=0.4`), so sweeps and
    searches reach it. Placement: exactly one of `path`, `bay`, `between` or `relative`."""

    role: str = "target"  # ego | target | occluder | parked | moving
    kind: str = "vehicle"  # vehicle | person | box
    # vehicle: a model by name, or drawn by size class (small | medium | large), colour and body (car, van, ...);
    # colour `palette`: one copy per palette target colour, one variant each (the research's black and white cars)
    model: str = ""
    size: str = ""
    colour: str = ""
    body: str = ""
    # person: age group, height (m, None: the group's usual), build, pose (standing | walking | crouching),
    # clothing palette
    age: str = "adult"
    height: Optional[float] = None
    build: str = "average"
    gender: str = "neutral"
    pose: str = "standing"
    clothing: str = "default"
    # box (a static occluder): its size in metres (height shared with people), colour by name
    length: Optional[float] = None
    width: Optional[float] = None
    # placement
    path: str = ""  # a path of the site: `distance` metres along it, `offset` to its left
    distance: float = 0.0
    offset: float = 0.0
    yaw: float = 0.0  # degrees, added to the heading the placement gives
    align: str = "centre"  # centre: distance is the actor's centre; start: its rear, from the path's start
    clip: bool = False  # with path: a distance the path has no room for is trimmed to its room (else an error);
    # with relative: trimmed to the room of the path the other actor stands on
    before: str = ""  # with path: distance counted back from this bay, or from this actor
    bay: str = ""  # in this bay of the site (a name from `bays`, or an index), nose to the lane
    gap: Optional[float] = None  # in a bay: front bumper this far behind the bay line (None: centred); with
    # `relative`: it stands before the other actor (towards the ego), this much free floor between them
    between: list[str] = field(default_factory=list)  # in the gap between two bays ...
    out: float = 0.0  # ... this far past the bay line into the lane
    relative: str = ""  # `distance` ahead of this actor (or of `focus`) along its heading, `offset` to its left
    nearest_bay: int = -1  # in the k-th free bay nearest the site's focus (0: the nearest), nose to the lane
    # One key for what the actor is (scenario/actors.py: resolve_type): a vehicle model's name (any of the
    # library's), `child`, `adult`, `crouching` (an adult crouching) or `pillar` (a box painted as the pillars);
    # empty: `kind`, `model`, `age`, `pose` as written. A search's `choice(...)` over vehicles and people in one
    # factor.
    type: str = ""
    # A person's height as a fraction 0-1 of its age group's range (assets/people.py: STATURE, the 5th to 95th
    # percentile); None: `height` (or the group's usual). One factor for children and adults alike.
    stature: Optional[float] = None
    # A vehicle's paint (scenario/actors.py: paint), HLS: hue in degrees (0-360), saturation and lightness 0-1;
    # all None: the model's own paint. Any one set paints it (the others from 0 hue, 0.5 saturation, 0.5 lightness).
    hue: Optional[float] = None
    saturation: Optional[float] = None
    lightness: Optional[float] = None


@dataclass
class OccluderConf:
    """The occluder arrangement, composed with any scenario: the site's pillar kept or removed, and actors of
    its own placed around the site's focus (the pillar; else halfway between the ego and the target)."""

    name: str = "pillar"
    kind: str = "pillar"  # pillar: the site's pillar stands | none: it is removed
    size: Optional[float] = None  # the pillar's side (m); None: as the garage (and `pillar` factor) has it
    actors: dict[str, ActorConf] = field(default_factory=dict)  # shown in every variant of the scenario


@dataclass
class AlongConf:
    """An actor moving at the same time as the motion's (a person stepping out while the ego drives): its
    placement value `key` goes from `start` towards `end` at `speed` (m/s) from the frame where the motion's
    value passes `at` (None: from the first frame), or timed to reach `end` as the motion's value passes `meet`.
    The time of a frame is the ego's travel over `ego.speed`."""

    key: str = "out"  # distance | offset | yaw | out | gap
    start: float = 0.0
    end: float = 0.0
    speed: float = 1.4  # m/s (1.4: an adult's walking speed)
    at: Optional[float] = None
    values: list[float] = field(default_factory=list)  # instead: the value at each frame of the motion (the last
    # one held after), as an adversary's episode moved it (garage_exp/gym/export.py)
    accelerate: float = 0.0  # metres from standstill to `speed` at a constant acceleration (0: at speed at once;
    # Euro NCAP's pedestrian targets reach theirs after 1 m)
    meet: Optional[float] = None  # instead of `at`: start so as to reach `end` when the motion's value passes
    # `meet` (a synchronised arrival, as OpenSCENARIO's SynchronizeAction and the Euro NCAP protocols time it)
    path: list[list[float]] = field(default_factory=list)  # instead of start/end: the [distance, offset] points
    # it walks through at `speed`, the first where it stands (an imported polyline trajectory's vertices); it
    # turns as each leg turns from the first (key: distance or offset, the one an exported file reads)


@dataclass
class MotionConf:
    """The per-frame sweep: one placement value of one actor (its copies, for a palette-coloured actor)."""

    actor: str = ""  # empty: a static scenario (one frame per variant); `target` with no actor so named: each
    # variant's target
    key: str = "distance"  # distance | offset | yaw | out | gap
    start: Optional[float] = None
    end: Optional[float] = None
    step: float = 0.5
    values: list[float] = field(default_factory=list)  # instead of start/end/step
    along: dict[str, AlongConf] = field(default_factory=dict)  # actor -> its motion at the same time (the ego's)


@dataclass
class VariantConf:
    """A run of frames with some of the actors standing (the others wait out of the scene)."""

    label: str = ""  # the frame table's label; empty: the shown actors' names
    show: list[str] = field(default_factory=list)  # the actors besides the ego; empty: all of them
    target: str = ""  # the actor scored; empty: the scenario's target
    set: dict[str, Any] = field(default_factory=dict)  # "actor.key": value for this variant only


@dataclass
class CaseConf:
    """A scenario (one YAML file of the `case` group): a site of the plan, actors, a motion, variants."""

    name: str = MISSING
    # corner | bay_beside_pillar | straight_run | ... (garage_exp/scenario/sites.py), or your own site function:
    # {_target_: my_sites.ramp, ...its keyword arguments}
    site: Any = MISSING
    # which of the plan's sites of that kind (scenario/sites.py: ordered with the one nearest the entrance, or the
    # longest straight lane, first): site_index picks by its place (null: the first, the research's), site_draw
    # by a fraction of their count in [0, 1] (floor(draw x count), 1.0 the last: a search over garages with other
    # counts); a
    # site that does not host the case passes it to the next in order (docs/scenarios.md)
    site_index: Optional[int] = None
    site_draw: Optional[float] = None
    position_label: str = "position (m)"  # the plot's x axis: what the motion moves
    bays: dict[str, str] = field(default_factory=dict)  # names for the site's bays (far: 3, mine: right:2)
    keep_free: list[str] = field(default_factory=list)  # bays kept free of the palette's parked cars (besides
    # those the actors stand in)
    actors: dict[str, ActorConf] = field(default_factory=dict)
    motion: MotionConf = field(default_factory=MotionConf)
    variants: list[VariantConf] = field(default_factory=list)
    target: str = ""  # the actor scored when a variant does not say; empty: the actor with role target
    slots: bool = False  # score parking-slot finding on a bird's-eye view of the fisheye rig (camera.bev)
    camera: str = ""  # the rig's camera whose frames score the case (its summary, `late`): a reversing ego's
    # `rear`; empty: the rig's first camera
    # One-shot scenarios: K frames evenly along the motion (the first and the last among them), the trajectory's own
    # frames (its times and co-motions as the whole trajectory has them); None: every frame (a trajectory).
    # frames=1 is the motion's first frame: a scenario is one picture, and a search's budget counts scenarios.
    frames: Optional[int] = None


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


@dataclass
class SensorConf:
    """The camera sensor: `_target_` names the factory called with the other keys (name, kind, params)."""

    name: str = "ideal"
    _target_: str = "garage_exp.perception.sensor.make_sensor"
    kind: str = "ideal"  # ideal | noisy | camera
    params: dict[str, Any] = field(default_factory=dict)


@dataclass
class DetectorConf:
    """The detector under test: `_target_` names the factory of the composite detector, called with the other keys.
    Entries of `models`: perception.detect.entries (docs/perception.md)."""

    name: str = "coco3"
    _target_: str = "garage_exp.perception.detect.detector.make_detector"
    models: list[str] = field(default_factory=lambda: ["yolo11n_int8_openvino_model", "yolov8n_int8_openvino_model",
                                                         "yolo26n_int8_openvino_model"])
    classes: list[str] = field(default_factory=lambda: ["car", "truck", "bus"])  # a vehicle target's classes
    person_classes: list[str] = field(default_factory=lambda: ["person"])  # a pedestrian target's classes
    # A model's own class names -> vehicle | person, for models whose names are not COCO's ({Pedestrian: person}).
    class_map: dict[str, str] = field(default_factory=dict)
    # A model's class names by index, for models that cannot give their own (a stock KServe server, a function
    # without `classes`): its name (the frame table's conf_<name>) -> a list, or a YAML/JSON/text file of them.
    class_names: dict[str, Any] = field(default_factory=dict)
    conf: float = 0.05  # keep low detections: a miss scores 0, a weak hit its confidence
    iou: float = 0.5
    match: str = "full"  # full | visible | either
    threshold: float = 0.5  # composite confidence counted as detected
    imgsz: int = 640
    # The MLflow store that `models:/NAME/VERSION` entries are read from; None: $MLFLOW_TRACKING_URI, else
    # outputs/mlflow.db. By default the job's own store (tracking.uri), where `python -m garage_exp.train` registers.
    registry: Optional[str] = "${oc.select:tracking.uri,null}"
    # auto: .pt models on the first CUDA GPU when torch sees one, else the CPU; OpenVINO exports always on the CPU.
    # cpu | cuda (cuda without a CUDA GPU is refused). perception.detect.devices.pick_device.
    device: str = "auto"


@dataclass
class RendererConf:
    """The renderer: `_target_` names the backend's factory, called with the other keys, returning a
    `garage_exp.render.Renderer`."""

    name: str = "sapien"
    _target_: str = "garage_exp.render.sapien_backend.make"
    max_lights: int = 8
    shadows: bool = False
    save_frames: str = "key"  # all | key | none
    device: str = "auto"  # the Vulkan device: auto (a GPU when present, else lavapipe) | cpu | cuda (render.device)
    scenes: int = 1  # sub-scenes of the render scene: the shots rendered as one batch (render/batch.py)
    # loaded garages the SAPIEN renderer keeps: a job on one of the last N garages replaces only its actors and
    # cameras (a search across a few plans switches garages without rebuilding them); 1: the last one, as before
    kept_garages: int = 1


@dataclass
class TrackingConf:
    name: str = "mlflow"
    uri: Optional[str] = None  # None: $MLFLOW_TRACKING_URI, else sqlite:///<project>/outputs/mlflow.db
    experiment: str = "garage_exp"


@dataclass
class RequireConf:
    """What a space asks of a draw before it is rendered (None: no condition): the target at least
    `min_visible` visible, its box at least `min_box` pixels tall, at most `max_distance` metres from the camera,
    at most `max_truncation` of its box outside the image."""

    min_visible: Optional[float] = None
    min_box: Optional[float] = None
    max_distance: Optional[float] = None
    max_truncation: Optional[float] = None


@dataclass
class SpaceConf:
    """A search space shipped as a file (conf/space/NAME.yaml; `space=NAME`): `params` are overrides in the
    search's grammar (`key=interval(a,b)`, `key=choice(a,b)`, fixed `key=value`), taken as if written on the
    command line before the command's own (which win for the same key: garage_exp/search/space.py: expand);
    `require` its conditions on a draw. Both are the search's (`search.require`, `search.descriptors`) unless the
    command sets those itself (garage_exp/search/space.py: settle)."""

    name: str = "none"
    params: list[str] = field(default_factory=list)
    require: RequireConf = field(default_factory=RequireConf)
    # the archive's cells for this space: a named set of descriptors (search/schema.py: DESCRIPTOR_SETS);
    # None: the search's own (`search.descriptors`)
    descriptors: Optional[str] = None


@dataclass
class ReplicateConf:
    """What changes between the replicates of a cell (replicate 0 is the scenario as written): uniform draws in
    +-these ranges, seeded by (seed, replicate) so replicate k is the same in every cell and every rerun."""

    offset: float = 0.3  # each target's lateral offset (m)
    yaw: float = 5.0  # each target's yaw (degrees)
    ego_offset: float = 0.3  # the ego's lateral position (m)
    models: bool = True  # each vehicle target's model drawn from its size class and colour


# The top-level config's nodes, in its order. A node of a layer above core is declared beside its check in that
# layer and registered here by dotted name, resolved when the schema is first used (as a config's `_target_` is),
# so that core imports no layer above it. A new node: its dataclass beside its check, and one line here (and in
# GROUPS when it is a config group with YAML levels).
NODES: dict[str, type | str] = {
    "plan": PlanConf, "garage": GarageConf, "light": LightConf, "camera": CameraRigConf, "palette": PaletteConf,
    "occluder": OccluderConf, "case": CaseConf, "ego": "garage_exp.results.late.EgoConf", "sensor": SensorConf,
    "look": LookConf, "materials": MaterialsConf, "clutter": ClutterConf, "detector": DetectorConf,
    "slot_detector": "garage_exp.slots.schema.SlotDetectorConf", "renderer": RendererConf,
    "tracking": TrackingConf, "space": SpaceConf,
}


class ByName(str):
    """A node registered by dotted name among Shared's values, resolved in its place (config_schema)."""


@dataclass
class Shared:
    """The top-level config's own values, after its nodes (config_schema)."""

    # Extra factors: config groups whose YAML names a scene modifier with `_target_` (see conf/pillar/).
    modifiers: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    replicates: int = 1  # each cell run this many times with seeded nuisance variation (`replicate` node)
    replicate: ReplicateConf = field(default_factory=ReplicateConf)
    search: Any = ByName("garage_exp.search.schema.SearchConf")  # the sweeper's settings (search/schema.py)
    blank: bool = False  # the blank control: only the vehicles, background removed
    dataset: bool = False  # also write frames with YOLO, COCO and KITTI labels (garage_exp/exports)
    export: Any = ByName("garage_exp.openscenario.checks.ExportConf")  # formats beside the frames
    resume: bool = False
    dry_run: bool = False  # plan + map + MLflow only: no rendering or detection


GROUPS: dict[str, type | str] = {
    "plan": PlanConf, "garage": GarageConf, "light": LightConf, "camera": CameraRigConf, "palette": PaletteConf,
    "occluder": OccluderConf, "case": CaseConf, "sensor": SensorConf, "detector": DetectorConf,
    "look": LookConf, "materials": MaterialsConf, "clutter": ClutterConf,
    "slot_detector": "garage_exp.slots.schema.SlotDetectorConf", "renderer": RendererConf,
    "tracking": TrackingConf, "space": SpaceConf,
}
# Names that moved beside their checks, still importable from here for code written before the move.
MOVED = {"EgoConf": "garage_exp.results.late.EgoConf", "SearchConf": "garage_exp.search.schema.SearchConf",
         "SuiteConf": "garage_exp.search.schema.SuiteConf", "PrescreenConf": "garage_exp.search.schema.PrescreenConf",
         "SlotDetectorConf": "garage_exp.slots.schema.SlotDetectorConf",
         "SlotLinesConf": "garage_exp.slots.schema.SlotLinesConf",
         "SlotMetricsConf": "garage_exp.slots.schema.SlotMetricsConf",
         "ExportConf": "garage_exp.openscenario.checks.ExportConf"}


def schema_of(entry: type | str) -> type:
    """A registered schema: the dataclass, or the one its dotted name names."""
    if isinstance(entry, type):
        return entry
    module, _, name = entry.rpartition(".")
    return getattr(importlib.import_module(module), name)


@STATE.memo("process", maxsize=None)
def config_schema() -> type:
    """The top-level config's dataclass (`Config`): every node of NODES, then Shared's values (a node registered
    by name among them in its place), in the config's order."""
    fields = [(name, schema_of(entry)) for name, entry in NODES.items()]
    for f in dataclasses.fields(Shared):
        if isinstance(f.default, ByName):
            fields.append((f.name, schema_of(f.default)))
        else:
            fields.append((f.name, f.type, field(default=f.default, default_factory=f.default_factory)))
    spec = [(n, t, field(default_factory=t)) if not rest else (n, t, *rest) for n, t, *rest in fields]
    config = dataclasses.make_dataclass("Config", spec)
    config.__module__ = __name__  # its annotations name this module's types
    return config


def __getattr__(name: str):
    """`Config` (built once, config_schema) and the names that moved (MOVED)."""
    if name == "Config":
        return config_schema()
    if name in MOVED:
        return schema_of(MOVED[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# What register() last stored: (group, name, dataclass) -> the ConfigStore entry it made.
_STORED = STATE.cache("core.schema.stored", "process")


def register() -> None:
    """Store the config schema and each group's schema in Hydra's ConfigStore. Every command calls it (and every
    composition outside one); storing converts each dataclass (OmegaConf.structured, 0.1-0.2 s in all), so a
    dataclass whose entry is still in the store is not stored again: a process running many commands (a test
    session, a notebook) pays it once."""
    cs = ConfigStore.instance()
    # A group, so that a command whose config composes the experiment's (conf/gym.yaml) types it with its own
    # subclass of Config: `override config_schema: gym`.
    nodes = [("config_schema", "experiment", config_schema(), "_global_")]
    nodes += [(group, f"{group}_schema", schema_of(schema), None) for group, schema in GROUPS.items()]
    for group, name, node, package in nodes:
        entries = cs.repo.get(group, {})
        if _STORED.get((group, name, node)) is None or entries.get(f"{name}.yaml") is not _STORED[group, name, node]:
            cs.store(group=group, name=name, node=node, package=package)
            _STORED[group, name, node] = cs.repo[group][f"{name}.yaml"]
