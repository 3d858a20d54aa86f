"""The vehicle library: FlightGear .ac models as Z-up, nose-along-+x GLB files with real-size metadata.

Each model is converted on first use (`VehicleModel.glb`) into <cache>/vehicles/<name>-<hash>.glb, where the
hash covers the .ac bytes, the textures it names and CONVERTER_VERSION, so a converter fix invalidates old
files. The metadata of all
models (extents, colour) is cheap to compute and kept in one JSON beside them.

Conversion: keep the nearest level of detail; rotate Y up to Z up with the length along x and the nose at +x;
recentre so the bounding box is centred on x = y = 0 with the wheels at z = 0; no emission; specular at most
0.2 and no transparency (AC3D `spec 1 1 1` and `trans` lines render whole cars white); drop headlight beams
(translucent glowing surfaces); fix the scale of the models listed in SCALE.

Size classes by real dimensions (the research's small / medium / large parked cars):
- small: length < 4.4 m (hatchbacks, compact cars);
- medium: 4.4 m <= length <= 5.0 m and height < 1.9 m (sedans, estates, compact SUVs);
- large: everything else (pickups, vans, minibuses, buses, trucks).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from garage_exp.core import paths
from garage_exp.assets.ac3d import AcFile, MeshPart, mesh_parts, nearest_lod, read_ac, to_scene
from garage_exp.assets.locate import vehicles_dir
from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE
from garage_exp.scene.kinds import kind_of

log = logging.getLogger(__name__)

# Bump whenever the conversion changes what a GLB or the metadata holds.
CONVERTER_VERSION = 4

SMALL_MAX_LENGTH = 4.4
MEDIUM_MAX_LENGTH = 5.0
MEDIUM_MAX_HEIGHT = 1.9
# Plausible road vehicles; a model outside these is mis-scaled or carries stray geometry.
LENGTH_RANGE = (3.0, 13.0)
WIDTH_RANGE = (1.4, 2.7)
HEIGHT_RANGE = (1.1, 4.2)
MAX_SPEC = 0.2
# Colour words from texture samples (0-1 value and saturation; hue ranges in degrees).
BLACK_MAX_VALUE = 0.2
SILVER_MAX_VALUE = 0.55
GREY_MAX_SAT = 0.2
BLACK_MIN_SHARE = 0.65
HUES = (("red", 330, 360), ("red", 0, 20), ("yellow", 35, 75), ("green", 75, 170), ("blue", 190, 260))

SIZE_CLASSES = ("small", "medium", "large")
COLOURS = ("black", "white", "silver", "red", "blue", "green", "yellow", "other")
KINDS = ("car", "suv", "pickup", "van", "bus", "truck")

# Models whose nose the automatic rule puts at -x (checked by rendering side views): turned 180 degrees.
NOSE_FLIP: frozenset[str] = frozenset({"it_policecar1"})

# Models built at the wrong scale: the two gr_* models are 1.33x too large (wheels about 0.85 m across, the
# Citroen Xsara police car 5.6 m long instead of 4.2 m, the Ducato ambulance 7.8 m instead of 5.8 m).
SCALE: dict[str, float] = {"gr_policar1": 0.75, "gr_paramedic1": 0.75}

# Colour words in model names; the first that matches wins.
_COLOUR_WORDS = (("yel", "yellow"), ("black", "black"), ("white", "white"), ("silver", "silver"), ("red", "red"),
                 ("blue", "blue"), ("green", "green"), ("yellow", "yellow"))

# Y-up file frame to Z-up vehicle frame. Length along file z: x' = -z, y' = -x, z' = y (FACTS.md).
_FROM_Z_LENGTH = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# Length along file x (hatchbacks, vans, bus-muc, motorhome, trucks): their nose is at file -x, so
# x' = -x, y' = z, z' = y.
_FROM_X_LENGTH = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
_TURN = np.diag([-1.0, -1.0, 1.0])


def colour_from_name(name: str) -> str | None:
    lower = name.lower()
    return next((colour for word, colour in _COLOUR_WORDS if word in lower), None)


def colour_words(rgb: np.ndarray) -> np.ndarray:
    """A colour word per 0-1 RGB row. Greys split by value; thresholds tuned on the models whose name says
    their colour (31 of 37 agree; the misses are white versus silver, which baked-in shading blurs)."""
    high, low = rgb.max(axis=1), rgb.min(axis=1)
    sat = np.where(high > 0, (high - low) / np.maximum(high, 1e-9), 0.0)
    span = np.maximum(high - low, 1e-9)
    r, g, b = rgb.T
    hue = np.where(high == r, ((g - b) / span) % 6, np.where(high == g, (b - r) / span + 2, (r - g) / span + 4))
    deg = hue * 60.0
    out = np.full(len(rgb), "other", dtype=object)
    grey = (sat < GREY_MAX_SAT) | (high < BLACK_MAX_VALUE)
    out[grey] = np.where(high[grey] < BLACK_MAX_VALUE, "black",
                         np.where(high[grey] < SILVER_MAX_VALUE, "silver", "white"))
    for word, lo, hi in HUES:
        out[~grey & (deg >= lo) & (deg < hi)] = word
    return out


def dominant_colour(shares: dict[str, float]) -> str:
    """The body colour from area shares: windows, tyres and shadows are dark, so black wins only when it
    covers most of the car; otherwise the largest other colour does."""
    others = {k: v for k, v in shares.items() if k != "black"}
    if shares.get("black", 0.0) > BLACK_MIN_SHARE or not others:
        return "black"
    return max(others, key=others.get)


def size_class_of(length: float, height: float) -> str:
    if length < SMALL_MAX_LENGTH:
        return "small"
    if length <= MEDIUM_MAX_LENGTH and height < MEDIUM_MAX_HEIGHT:
        return "medium"
    return "large"


# The size classes the library files each kind under (its models, above): cars are small or medium (none is over
# 5.0 m long or 1.9 m tall), SUVs medium, and everything large is a pickup, van, bus or truck. An importer asking
# for a vehicle by its size and kind asks for one of these (garage_exp/openscenario/xosc_import.py).
SIZES_OF_KIND = {"car": ("small", "medium"), "suv": ("medium",), "pickup": ("large",), "van": ("large",),
                 "bus": ("large",), "truck": ("large",)}


def size_class_for(kind: str, length: float, height: float) -> str:
    """The size class a vehicle of `kind` and this size is drawn from: its own (size_class_of), else the nearest
    one the library holds of that kind."""
    own = size_class_of(length, height)
    held = SIZES_OF_KIND[kind]
    if own in held:
        return own
    return min(held, key=lambda c: abs(SIZE_CLASSES.index(c) - SIZE_CLASSES.index(own)))


def source_hash(source: Path) -> str:
    """Hash of the .ac, the textures it names and the converter version (what a GLB is made of)."""
    data = source.read_bytes()
    digest = hashlib.sha256(data)
    for texture in sorted(set(re.findall(rb'^texture\s+"([^"]+)"', data, flags=re.MULTILINE))):
        path = source.parent / texture.decode("latin-1")
        digest.update(texture + (path.read_bytes() if path.exists() else b"missing"))
    digest.update(f"converter-{CONVERTER_VERSION}".encode())
    return digest.hexdigest()[:16]


@dataclass
class Converted:
    """A model in the vehicle frame: its file, kept parts and the transform (rotation and scale) placing them."""

    ac: AcFile
    parts: list[MeshPart]
    transform: np.ndarray  # 4x4, file frame -> vehicle frame
    extents: np.ndarray  # length, width, height


def convert(source: Path) -> Converted:
    """Read an .ac vehicle and work out its placement and looks (no file written)."""
    ac = read_ac(source)
    # Translucent glowing surfaces are headlight beams (YellowContainerTruck's reach 3.5 m ahead), not body.
    beams = {i for i, m in enumerate(ac.materials) if m.trans > 0 and max(m.emis) > 0}
    for mat in ac.materials:
        mat.emis = (0.0, 0.0, 0.0)
        mat.spec = tuple(min(s, MAX_SPEC) for s in mat.spec)
        mat.trans = 0.0
    parts = [p for p in mesh_parts(ac, nearest_lod(ac.world)) if p.material not in beams]
    if not parts:
        raise GarageError("holds no polygons", str(source))
    points = np.concatenate([p.vertices for p in parts])
    span = points.max(0) - points.min(0)
    rot = _FROM_Z_LENGTH if span[2] >= span[0] else _FROM_X_LENGTH
    if source.stem in NOSE_FLIP:
        rot = _TURN @ rot
    rot = rot * SCALE.get(source.stem, 1.0)
    turned = points @ rot.T
    low, high = turned.min(0), turned.max(0)
    transform = np.eye(4)
    transform[:3, :3] = rot
    transform[:3, 3] = [-(low[0] + high[0]) / 2, -(low[1] + high[1]) / 2, -low[2]]
    return Converted(ac, parts, transform, high - low)


def colour_shares(conv: Converted) -> dict[str, float]:
    """Area share of each colour word over the surfaces (texture at face centres times material rgb)."""
    from PIL import Image

    images: dict[str, np.ndarray] = {}
    words, areas = [], []
    for part in conv.parts:
        tri = part.vertices[part.faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        colour = np.tile(np.array(conv.ac.materials[part.material].rgb, float), (len(area), 1))
        if part.texture:
            if part.texture not in images:
                with Image.open(conv.ac.path.parent / part.texture) as img:
                    images[part.texture] = np.asarray(img.convert("RGB"), float) / 255.0
            image = images[part.texture]
            h, w = image.shape[:2]
            uv = part.uvs[part.faces].mean(axis=1) % 1.0
            # AC3D's v runs bottom-up, image rows top-down.
            cols = np.minimum((uv[:, 0] * w).astype(int), w - 1)
            rows = np.minimum(((1.0 - uv[:, 1]) * h).astype(int), h - 1)
            colour = colour * image[rows, cols]
        words.append(colour_words(colour))
        areas.append(area)
    word, area = np.concatenate(words), np.concatenate(areas)
    total = area.sum()
    return {w: float(area[word == w].sum() / total) for w in np.unique(word)} if total > 0 else {}


def _plausible(extents: np.ndarray) -> str | None:
    """None for a road vehicle's extents, else why not."""
    for value, (low, high), what in zip(extents, (LENGTH_RANGE, WIDTH_RANGE, HEIGHT_RANGE),
                                        ("length", "width", "height")):
        if not low <= value <= high:
            return f"{what} {value:.2f} m outside {low}-{high} m"
    return None


def write_glb(conv: Converted, target: Path) -> Path:
    """Export the converted model."""
    scene = to_scene(conv.ac, conv.parts, conv.transform)
    return write_atomic(scene.export(file_type="glb", include_normals=True), target)


def write_atomic(data: bytes, target: Path) -> Path:
    """Write to a temp file and rename, so readers (other jobs sharing the cache) never see half a file."""
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=target.stem, suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; the cache is shared by whoever runs experiments here
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target


@dataclass(frozen=True)
class VehicleModel:
    """One vehicle: real size in metres (length along x, nose at +x), classes, and its GLB (made on first use)."""

    name: str
    length: float
    width: float
    height: float
    size_class: str
    colour: str
    kind: str
    source: Path = field(repr=False)
    glb_path: Path = field(repr=False)

    @property
    def glb(self) -> str:
        """Path of the GLB, converting the .ac now if no process has done it yet."""
        if not self.glb_path.exists():
            log.info("converting %s -> %s", self.source.name, self.glb_path.name)
            write_glb(convert(self.source), self.glb_path)
        return str(self.glb_path)

    def fits(self, ceiling_h: float) -> bool:
        """Whether it passes under a ceiling with 0.1 m to spare."""
        return self.height + 0.1 < ceiling_h


def _metadata(source: Path) -> dict:
    conv = convert(source)
    length, width, height = (round(float(v), 4) for v in conv.extents)
    colour = colour_from_name(source.stem) or dominant_colour(colour_shares(conv))
    return {"length": length, "width": width, "height": height, "colour": colour,
            "excluded": _plausible(conv.extents)}


class VehicleLibrary:
    """The road vehicles in a folder of .ac files (default: `locate.vehicles_dir()`), sorted by name."""

    def __init__(self, root: Path | None = None):
        self.root = Path(root) if root is not None else vehicles_dir()
        sources = sorted(self.root.glob("*.ac"))
        if not sources:
            raise GarageError("holds no .ac files", str(self.root))
        self.cache = paths.cache_dir() / "vehicles"
        self.cache.mkdir(parents=True, exist_ok=True)
        self.excluded: dict[str, str] = {}
        meta = self._load_metadata(sources)
        models = []
        for source in sources:
            name = source.stem
            entry = meta[name]
            if entry["excluded"]:
                self.excluded[name] = entry["excluded"]
                # Said once at set-up (`python -m garage_exp.assets ensure`), not by every command.
                log.debug("vehicle %s excluded: %s", name, entry["excluded"])
                continue
            models.append(VehicleModel(
                name=name, length=entry["length"], width=entry["width"], height=entry["height"],
                size_class=size_class_of(entry["length"], entry["height"]), colour=entry["colour"],
                kind=kind_of(name), source=source, glb_path=self.cache / f"{name}-{entry['hash']}.glb"))
        self.models: list[VehicleModel] = sorted(models, key=lambda m: m.name)
        self._by_name = {m.name: m for m in self.models}

    def _load_metadata(self, sources: list[Path]) -> dict[str, dict]:
        """Per-model metadata, computed only for models whose hash is not in the JSON yet."""
        path = self.cache / "metadata.json"
        try:
            known = json.loads(path.read_text())
        except (OSError, ValueError):
            known = {}
        out, changed = {}, False
        for source in sources:
            digest = source_hash(source)
            entry = known.get(source.stem)
            if not entry or entry.get("hash") != digest:
                entry = {"hash": digest, **_metadata(source)}
                changed = True
            out[source.stem] = entry
        if changed:
            fd, tmp = tempfile.mkstemp(prefix="metadata", suffix=".tmp", dir=self.cache)
            with os.fdopen(fd, "w") as f:
                json.dump({**known, **out}, f, indent=1, sort_keys=True)
            os.replace(tmp, path)
        return out

    def get(self, name: str) -> VehicleModel:
        if name in self._by_name:
            return self._by_name[name]
        if name in self.excluded:
            raise GarageError(f"vehicle model '{name}' is excluded ({self.excluded[name]})", str(self.root))
        raise GarageError(f"unknown vehicle model '{name}'; known: {', '.join(self._by_name)}", str(self.root))

    def choose(self, size_class: str | None = None, colour: str | None = None, kind: str | None = None,
               max_height: float | None = None, rng: np.random.Generator | None = None,
               max_length: float | None = None, max_width: float | None = None) -> VehicleModel:
        """A model matching every given filter, drawn with rng (a fixed seed when None): same rng, same pick."""
        for value, allowed, what in ((size_class, SIZE_CLASSES, "size_class"), (colour, COLOURS, "colour"),
                                     (kind, KINDS, "kind")):
            if value is not None and value not in allowed:
                raise GarageError(f"unknown {what} '{value}'; one of {', '.join(allowed)}", "vehicles.choose")
        candidates = [m for m in self.models
                      if (size_class is None or m.size_class == size_class)
                      and (colour is None or m.colour == colour)
                      and (kind is None or m.kind == kind)
                      and (max_height is None or m.height <= max_height)
                      and (max_length is None or m.length <= max_length)
                      and (max_width is None or m.width <= max_width)]
        if not candidates:
            asked = {"size_class": size_class, "colour": colour, "kind": kind, "max_height": max_height,
                     "max_length": max_length, "max_width": max_width}
            filters = ", ".join(f"{k}={v}" for k, v in asked.items() if v is not None) or "no filter"
            raise GarageError(f"no vehicle model matches {filters}", str(self.root))
        rng = rng if rng is not None else np.random.default_rng(0)
        return candidates[int(rng.integers(len(candidates)))]


_LIBRARIES: dict[Path, VehicleLibrary] = STATE.cache("assets.vehicles.libraries", "process")


def shared_library(root: Path | None = None) -> VehicleLibrary:
    """The process's library of a folder: read once (its metadata scan is 0.05 s, paid by every job of a
    sweep or search otherwise). The folder's .ac files are not expected to change during a process."""
    key = Path(root) if root is not None else vehicles_dir()
    if key not in _LIBRARIES:
        _LIBRARIES[key] = VehicleLibrary(key)
    return _LIBRARIES[key]

