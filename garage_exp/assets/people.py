"""The people library: human bodies from `anny` (a parametric body model on MakeHuman's CC0 assets) as Z-up,
metre, face-along-+x GLB files with a JSON sidecar.

A body is made of an age group, a height, a build, a gender, a pose and clothing colours. Each parameter set has
its own file name, <cache>/people/<name>-<hash>.glb (SAPIEN caches visual meshes by file path, so two bodies
must never share one), and the hash covers every parameter, BUILDER_VERSION and anny's version, so a change to
how bodies are made invalidates old files. Building needs anny's model (about a minute the first time a machine
loads it, then about a second; its cache lives in <cache>/anny); a cached body needs neither anny nor torch.

How a body is made:
- anny's phenotype (age, gender, weight, muscle, height) gives the shape; the height phenotype is interpolated
  to come near the asked height and the standing body is then scaled exactly to it (the walking body gets the
  same scale, so it stands a little lower);
- the pose rotates bones in anny's world-aligned reference frames: the rest pose has the arms 45 degrees out,
  "standing" brings them down, "walking" is mid-stride with the arms swinging against the legs;
- anny's bodies face -y: the body is turned to face +x, centred on x = y = 0 (its bounding box, as the vehicle
  GLBs are) with the feet at z = 0;
- clothing regions come from anny's skinning weights (each vertex goes to the region whose bones weigh most on
  it; hair is the top and back of the head), one plain PBR material per region.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import time
from dataclasses import asdict, dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from garage_exp.core import paths
from garage_exp.assets.vehicles import write_atomic
from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE

log = logging.getLogger(__name__)

# Bump whenever building changes what a GLB or its sidecar holds.
BUILDER_VERSION = 2

# anny's age phenotype (0-1): 0.25 is a child of about 1.2 m, 0.5 a young adult.
AGE_GROUPS = {"adult": 0.5, "child": 0.25}
DEFAULT_HEIGHT = {"adult": 1.75, "child": 1.2}
HEIGHT_RANGE = {"adult": (1.4, 2.1), "child": (0.9, 1.5)}
# An actor's `stature` 0-1 spans these heights (m): adults from a short woman's 5th percentile to a tall man's
# 95th (ISO 7250-1 style surveys: about 1.52 and 1.90 m); children about 4 to 10 years old (WHO growth
# references: about 1.00 m at 4, 1.45 m at 10).
STATURE = {"adult": (1.52, 1.90), "child": (1.0, 1.45)}
# (weight, muscle) phenotypes.
BUILDS = {"slim": (0.15, 0.4), "average": (0.5, 0.5), "heavy": (0.95, 0.55), "athletic": (0.4, 0.9)}
GENDERS = {"male": 0.0, "female": 1.0, "neutral": 0.5}
POSES = ("standing", "walking", "crouching")
REGIONS = ("skin", "hair", "shirt", "trousers", "shoes")

# Clothing colours, sRGB 0-255. A `clothing` dict picks a base outfit with "outfit" (default "default") and
# overrides regions by name, each a palette name or an [r, g, b] list.
PALETTE = {
    "skin_light": (224, 184, 150), "skin_medium": (190, 140, 100), "skin_dark": (110, 75, 50),
    "black": (25, 25, 28), "dark_brown": (60, 40, 25), "blond": (200, 170, 110), "grey": (120, 120, 120),
    "white": (235, 235, 230), "red": (190, 35, 35), "blue": (40, 75, 170), "navy": (30, 35, 70),
    "green": (50, 120, 60), "yellow": (230, 200, 40), "orange": (235, 120, 30), "denim": (60, 80, 120),
    "khaki": (170, 150, 110), "brown": (100, 65, 40), "pink": (230, 130, 160),
}
OUTFITS = {
    "default": {"skin": "skin_medium", "hair": "dark_brown", "shirt": "red", "trousers": "denim", "shoes": "black"},
    "dark": {"skin": "skin_dark", "hair": "black", "shirt": "black", "trousers": "navy", "shoes": "black"},
    "bright": {"skin": "skin_light", "hair": "blond", "shirt": "yellow", "trousers": "blue", "shoes": "white"},
    "grey": {"skin": "skin_light", "hair": "grey", "shirt": "grey", "trousers": "grey", "shoes": "grey"},
    "green": {"skin": "skin_medium", "hair": "black", "shirt": "green", "trousers": "khaki", "shoes": "brown"},
    "pink": {"skin": "skin_light", "hair": "blond", "shirt": "pink", "trousers": "white", "shoes": "pink"},
}

# Bones by name prefix -> clothing region (long sleeves, long trousers). Eyes go with the hair (dark).
_REGION_OF_BONE = (("finger", "skin"), ("metacarpal", "skin"), ("wrist", "skin"), ("neck", "skin"),
                   ("head", "skin"), ("eye", "hair"), ("foot", "shoes"), ("toe", "shoes"),
                   ("pelvis", "trousers"), ("upperleg", "trousers"), ("lowerleg", "trousers"),
                   ("root", "trousers"), ("spine", "shirt"), ("clavicle", "shirt"), ("shoulder", "shirt"),
                   ("upperarm", "shirt"), ("lowerarm", "shirt"))
# Degrees about anny's world-aligned axes (x: the body's left, -y: where it faces, z: up) per bone and pose.
# The rest pose holds the arms 45 degrees out with the elbows bent forward: the upper arms come down (about y)
# and the forearms straighten (about x), the legs come a little closer (about y). Walking: mid-stride, left leg
# ahead, arms swinging against the legs.
_ARMS_DOWN = 36.0
_LEGS_IN = 3.0  # the rest pose stands with the feet wide apart
_POSE_ANGLES = {
    "standing": {"upperarm01.L": (0.0, _ARMS_DOWN, 0.0), "upperarm01.R": (0.0, -_ARMS_DOWN, 0.0),
                 "lowerarm01.L": (40.0, 0.0, 0.0), "lowerarm01.R": (40.0, 0.0, 0.0),
                 "upperleg01.L": (0.0, _LEGS_IN, 0.0), "upperleg01.R": (0.0, -_LEGS_IN, 0.0)},
    "walking": {"upperarm01.L": (20.0, _ARMS_DOWN, 0.0), "upperarm01.R": (-20.0, -_ARMS_DOWN, 0.0),
                "lowerarm01.L": (40.0, 0.0, 0.0), "lowerarm01.R": (25.0, 0.0, 0.0),
                "upperleg01.L": (-22.0, _LEGS_IN, 0.0), "upperleg01.R": (14.0, -_LEGS_IN, 0.0),
                "lowerleg01.L": (8.0, 0.0, 0.0), "lowerleg01.R": (22.0, 0.0, 0.0),
                "foot.R": (-10.0, 0.0, 0.0)},
    # Crouching (a person tying a shoe or reaching under a car, case=crouch): thighs up, knees folded, the back
    # leaning forward and the arms reaching ahead to the knees; about 55 % of the standing height.
    "crouching": {"upperarm01.L": (-60.0, _ARMS_DOWN, 0.0), "upperarm01.R": (-60.0, -_ARMS_DOWN, 0.0),
                  "lowerarm01.L": (40.0, 0.0, 0.0), "lowerarm01.R": (40.0, 0.0, 0.0),
                  "upperleg01.L": (-120.0, 8.0, 0.0), "upperleg01.R": (-120.0, -8.0, 0.0),
                  "lowerleg01.L": (150.0, 0.0, 0.0), "lowerleg01.R": (150.0, 0.0, 0.0),
                  "foot.L": (-30.0, 0.0, 0.0), "foot.R": (-30.0, 0.0, 0.0), "spine03": (25.0, 0.0, 0.0)},
}
# The trousers' waistband above the hip joints, as a share of stature.
_BELT = 0.045
_ARM_BONES = ("clavicle", "shoulder", "upperarm", "lowerarm")

_MODEL = STATE.cache("assets.people.model", "process")  # anny's model, loaded once per process


@dataclass(frozen=True)
class BodySpec:
    """Everything that makes one body (the cache key)."""

    age_group: str = "adult"
    height: float = 1.75
    build: str = "average"
    gender: str = "neutral"
    pose: str = "standing"
    colours: tuple[tuple[str, tuple[int, int, int]], ...] = ()  # (region, sRGB) in REGIONS order

    @property
    def name(self) -> str:
        return f"{self.age_group}-{self.gender}-{self.build}-{self.pose}-{round(self.height * 100)}cm"

    def digest(self) -> str:
        text = json.dumps({**asdict(self), "builder": BUILDER_VERSION, "anny": _anny_version()}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:12]


@dataclass(frozen=True)
class PersonModel:
    """One body: real size in metres (length along x, where it faces; feet at z = 0), its GLB and sidecar."""

    name: str
    glb: str
    length: float  # extent along x (front to back, "depth")
    width: float  # extent along y (shoulder to shoulder)
    height: float
    age_group: str
    build: str
    gender: str
    pose: str
    colours: dict[str, tuple[int, int, int]]
    kind: str = "person"

    @property
    def depth(self) -> float:
        return self.length

    @property
    def extent(self) -> tuple[float, float, float]:
        return (self.length, self.width, self.height)

    @property
    def coco_class(self) -> str:
        return "person"


def resolve_colours(clothing: str | dict, where: str = "people.clothing"
                    ) -> tuple[tuple[str, tuple[int, int, int]], ...]:
    """Region colours from an outfit name or a dict (see OUTFITS and PALETTE)."""
    if isinstance(clothing, str):
        outfit, overrides = clothing, {}
    else:
        overrides = dict(clothing)
        outfit = str(overrides.pop("outfit", "default"))
    if outfit not in OUTFITS:
        raise GarageError(f"unknown outfit {outfit!r} (one of {', '.join(OUTFITS)})", where)
    unknown = set(overrides) - set(REGIONS)
    if unknown:
        raise GarageError(f"unknown clothing regions {sorted(unknown)} (one of {', '.join(REGIONS)})", where)
    chosen = {**OUTFITS[outfit], **overrides}
    out = []
    for region in REGIONS:
        value = chosen[region]
        if isinstance(value, str):
            if value not in PALETTE:
                raise GarageError(f"unknown colour {value!r} for {region} (one of {', '.join(PALETTE)})",
                                  f"{where}.{region}")
            rgb = PALETTE[value]
        else:
            rgb = tuple(int(c) for c in value)
            if len(rgb) != 3 or not all(0 <= c <= 255 for c in rgb):
                raise GarageError(f"colour {list(value)} for {region} is not three values in 0-255",
                                  f"{where}.{region}")
        out.append((region, rgb))
    return tuple(out)


def make_spec(age_group: str = "adult", height: float | None = None, build: str = "average",
              gender: str = "neutral", pose: str = "standing", clothing: str | dict = "default",
              where: str = "people") -> BodySpec:
    """A checked BodySpec; GarageError naming `where`.<parameter> for a bad value (a scenario passes its
    actor's key path, e.g. "case.actors.child")."""
    for value, allowed, what in ((age_group, AGE_GROUPS, "age_group"), (build, BUILDS, "build"),
                                 (gender, GENDERS, "gender"), (pose, POSES, "pose")):
        if value not in allowed:
            raise GarageError(f"unknown {what} {value!r} (one of {', '.join(allowed)})", f"{where}.{what}")
    height = DEFAULT_HEIGHT[age_group] if height is None else float(height)
    low, high = HEIGHT_RANGE[age_group]
    if not low <= height <= high:
        raise GarageError(f"height {height} m is outside {low}-{high} m for age group {age_group}", f"{where}.height")
    return BodySpec(age_group, round(height, 3), build, gender, pose, resolve_colours(clothing, f"{where}.clothing"))


# The small library `python -m garage_exp.assets ensure` builds: adults and children of a few heights and
# builds, standing and walking, in different clothes.
PREBUILT: tuple[BodySpec, ...] = tuple(
    make_spec(age, height, build, gender, pose, clothing)
    for age, height, build, gender, clothing, poses in (
        ("adult", 1.78, "average", "male", "default", ("standing", "walking")),
        ("adult", 1.65, "slim", "female", "bright", ("standing", "walking")),
        ("adult", 1.85, "heavy", "male", "dark", ("standing",)),
        ("adult", 1.60, "average", "female", "green", ("standing",)),
        ("child", 1.20, "average", "neutral", "bright", ("standing", "walking")),
        ("child", 1.10, "slim", "female", "pink", ("standing",)),
        ("child", 1.30, "average", "male", "default", ("standing",)),
        ("adult", 1.78, "average", "male", "default", ("crouching",)),  # case=crouch's
    )
    for pose in poses
)


class PeopleLibrary:
    """Bodies in <cache>/people: the prebuilt set (`library()`) and any other on demand (`body()`)."""

    def __init__(self, root: Path | None = None):
        self.root = Path(root) if root is not None else paths.cache_dir() / "people"
        self.root.mkdir(parents=True, exist_ok=True)
        self.built = 0  # bodies this library had to build (not found in the cache)

    def body(self, age_group: str = "adult", height: float | None = None, build: str = "average",
             pose: str = "standing", clothing: str | dict = "default", gender: str = "neutral",
             where: str = "people") -> PersonModel:
        """The body for these parameters, from the cache or built now (loads anny once per process). `where`
        names the parameters' place in error messages."""
        return self.get(make_spec(age_group, height, build, gender, pose, clothing, where))

    def get(self, spec: BodySpec) -> PersonModel:
        stem = f"{spec.name}-{spec.digest()}"
        glb, sidecar = self.root / f"{stem}.glb", self.root / f"{stem}.json"
        if not (glb.exists() and sidecar.exists()):
            start = time.perf_counter()
            meta = build_body(spec, glb)
            write_atomic(json.dumps(meta, indent=1).encode(), sidecar)
            self.built += 1
            log.info("built %s in %.2f s", glb.name, time.perf_counter() - start)
        meta = json.loads(sidecar.read_text())
        return PersonModel(name=spec.name, glb=str(glb), length=meta["length"], width=meta["width"],
                           height=meta["height"], age_group=spec.age_group, build=spec.build, gender=spec.gender,
                           pose=spec.pose, colours={k: tuple(v) for k, v in meta["colours"].items()})

    def library(self) -> list[PersonModel]:
        """The prebuilt bodies (built now if missing)."""
        return [self.get(spec) for spec in PREBUILT]


def _anny_version() -> str:
    try:
        return version("anny")
    except PackageNotFoundError:
        return "missing"


def load_anny():
    """anny's body model (once per process); its cache goes under ours unless ANNY_CACHE_DIR says otherwise."""
    if "anny" not in _MODEL:
        try:
            import anny
            from anny.paths import set_anny_cache_path
        except ImportError as exc:
            raise GarageError("building people needs the anny package: pip install anny", "people") from exc
        set_anny_cache_path(os.environ.get("ANNY_CACHE_DIR") or paths.cache_dir() / "anny")
        start = time.perf_counter()
        # Dual-quaternion skinning in torch: arms turned down keep their volume at the shoulder, and no warp.
        _MODEL["anny"] = anny.Anny(skinning_method="dqs")
        log.info("loaded anny in %.1f s", time.perf_counter() - start)
    return _MODEL["anny"]


def _rotation(angles: tuple[float, float, float]) -> np.ndarray:
    """4x4 rotation: about x, then y, then z (degrees)."""
    out = np.eye(4)
    for axis, deg in enumerate(angles):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        r = np.eye(3)
        i, j = (axis + 1) % 3, (axis + 2) % 3  # cyclic, so that each is a right-handed rotation
        r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
        step = np.eye(4)
        step[:3, :3] = r
        out = step @ out
    return out


def _posed(model, spec: BodySpec, height_phenotype: float, pose: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and bone head positions of the body in anny's frame."""
    import torch

    weight, muscle = BUILDS[spec.build]
    phenotype = {"age": AGE_GROUPS[spec.age_group], "gender": GENDERS[spec.gender], "weight": weight,
                 "muscle": muscle, "height": height_phenotype}
    bones = {name: torch.as_tensor(_rotation(angles), dtype=model.dtype)[None]
             for name, angles in _POSE_ANGLES[pose].items()}
    with torch.no_grad():
        out = model(pose_parameters=bones or None, phenotype_kwargs=phenotype)
    return out["vertices"][0].cpu().numpy().astype(float), out["bone_poses"][0, :, :3, 3].cpu().numpy().astype(float)


def _stature(vertices: np.ndarray) -> float:
    return float(vertices[:, 2].max() - vertices[:, 2].min())


def _height_phenotype(model, spec: BodySpec) -> float:
    """anny's height phenotype (0-1) nearest the asked height; anny's stature is close to linear in it."""
    low = _stature(_posed(model, spec, 0.0, "standing")[0])
    high = _stature(_posed(model, spec, 1.0, "standing")[0])
    return float(np.clip((spec.height - low) / (high - low), 0.0, 1.0))


def regions_of(model, vertices: np.ndarray, heads: np.ndarray) -> np.ndarray:
    """Clothing region index (into REGIONS) per face, from the skinning weights; the waistband and the hair
    from the body's shape.

    vertices, heads: the standing body and its bone heads in anny's frame (z up, facing -y)."""
    labels = list(model.bone_labels)
    bone_region = np.array([REGIONS.index(next((r for prefix, r in _REGION_OF_BONE if name.startswith(prefix)),
                                                "shirt")) for name in labels])
    weights = model.vertex_bone_weights.cpu().numpy()
    indices = model.vertex_bone_indices.cpu().numpy()
    faces = model.faces.cpu().numpy()
    score = np.zeros((len(weights), len(REGIONS)))
    np.add.at(score, (np.arange(len(weights))[:, None], bone_region[indices]), weights)
    region = score.argmax(axis=1)
    dominant = indices[np.arange(len(indices)), weights.argmax(axis=1)]
    z = vertices[:, 2]
    # Hair: head vertices above the brow, or behind the ears above the nape (anny faces -y).
    head = dominant == labels.index("head")
    eye = vertices[np.isin(dominant, [labels.index("eye.L"), labels.index("eye.R")])].mean(axis=0)
    size = z[head].max() - eye[2]  # about 0.12 m on an adult: scales the cuts to a child's head
    above_brow = z > eye[2] + 0.3 * size
    behind = (vertices[:, 1] > eye[1] + 1.0 * size) & (z > eye[2] - 0.6 * size)
    region[head & (above_brow | behind)] = REGIONS.index("hair")
    out = region[faces[:, 0]]
    # Hips and belly blend the spine's and the legs' weights: a straight waistband instead, trousers below it
    # and shirt above, decided per face so that the line follows the mesh (sleeves stay shirt).
    arm = np.isin(dominant, [k for k, name in enumerate(labels) if name.startswith(_ARM_BONES)])
    clothed = np.isin(region, [REGIONS.index("shirt"), REGIONS.index("trousers")]) & ~arm
    belt = heads[[labels.index("upperleg01.L"), labels.index("upperleg01.R")], 2].mean() + _BELT * _stature(vertices)
    body = clothed[faces].all(axis=1)
    out[body] = np.where(z[faces[body]].mean(axis=1) < belt, REGIONS.index("trousers"), REGIONS.index("shirt"))
    return out


def build_body(spec: BodySpec, target: Path) -> dict:
    """Make the body's GLB at `target`; its metadata (for the sidecar)."""
    import trimesh

    model = load_anny()
    height_phenotype = _height_phenotype(model, spec)
    standing, heads = _posed(model, spec, height_phenotype, "standing")
    scale = spec.height / _stature(standing)
    posed = standing if spec.pose == "standing" else _posed(model, spec, height_phenotype, spec.pose)[0]
    face_region = regions_of(model, standing, heads)
    # anny's frame (facing -y) turned 90 degrees about z to face +x: (x, y, z) -> (-y, x, z).
    vertices = np.stack([-posed[:, 1], posed[:, 0], posed[:, 2]], axis=1) * scale
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    vertices -= [(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, low[2]]
    faces = model.faces.cpu().numpy().astype(np.int64)
    body = trimesh.Trimesh(vertices, faces, process=False)
    normals = body.vertex_normals  # smooth normals over the whole body: no seams at the region borders
    colours = dict(spec.colours)
    scene = trimesh.Scene()
    for k, name in enumerate(REGIONS):
        chosen = np.flatnonzero(face_region == k)
        if not len(chosen):
            continue
        used, local = np.unique(faces[chosen], return_inverse=True)
        material = trimesh.visual.material.PBRMaterial(
            name=name, baseColorFactor=[*(c / 255.0 for c in colours[name]), 1.0], metallicFactor=0.0,
            roughnessFactor=0.45 if name == "hair" else 0.8)
        part = trimesh.Trimesh(vertices[used], local.reshape(-1, 3), vertex_normals=normals[used],
                               visual=trimesh.visual.TextureVisuals(material=material), process=False)
        scene.add_geometry(part, geom_name=name)
    write_atomic(scene.export(file_type="glb", include_normals=True), target)
    length, width, height = (round(float(v), 4) for v in vertices.max(axis=0) - vertices.min(axis=0))
    return {"name": spec.name, "length": length, "width": width, "height": height, "depth": length,
            "age_group": spec.age_group, "build": spec.build, "gender": spec.gender, "pose": spec.pose,
            "asked_height": spec.height, "colours": colours, "anny": _anny_version(), "builder": BUILDER_VERSION}
