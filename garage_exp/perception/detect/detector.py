"""The composite detector every caller gets, and the one factory that makes it.

`make_detector` is the `detector._target_`: called (through `core.plugins.build`, see `build_detector`) with the
`detector` group's keys, it resolves each entry of `detector.models` (entries.resolve) and returns a `Detector`.
Making one loads nothing and is cheap; it is plain picklable data (the detector's child process gets it whole).
`check()` loads every entry and runs each once on a probe frame: a job calls it before it writes anything.
`detect(frames)` runs every entry on a batch of frames; the research's composite (the mean of the models' best
matching confidences) is taken by `matching.score_target` from the per-model results.

Entries (base.Entry, one per model) may be of any registered kind (entries.py): ultralytics .pt (YOLO, RT-DETR),
OpenVINO exports, ONNX, TensorRT engines and TorchScript files; ONNX graphs through onnxruntime; torchvision
detection models; the user's own `callable:`. One detector may mix them.

Classes: a model's own class names are kept in its detections. The vehicle classes are `classes` plus every
name `class_map` maps to "vehicle"; the person classes `person_classes` plus those it maps to "person"
(`scoring()` gives both to `score_target`). A model none of whose names is a vehicle or person class is refused.
A model that cannot say its own names (a stock KServe server, a function without `classes`, an ONNX graph without
`names` metadata) is given them by `class_names` (its name -> a list of names, or a file holding them).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from garage_exp.core.errors import GarageError, check_range
from garage_exp.core.state import STATE
from garage_exp.perception.detect import entries as entry_kinds
from garage_exp.perception.detect.base import (WHERE, Detections, Entry, EntrySettings, as_batch,
                                               is_tensor, on_host, per_frame)
from garage_exp.perception.detect.devices import check_device, device_line
from garage_exp.perception.detect.matching import PERSON_CLASSES, VEHICLE_CLASSES
from garage_exp.scene.lenses import Lens

log = logging.getLogger("garage_exp")
GROUPS = ("vehicle", "person")
_SAID: dict[str, bool] = STATE.cache("perception.detect.said", "process")  # device lines this process logged


@dataclass
class Detector:
    """Several models (entries) run one after another on each batch of frames.

    models: resolved entries (paths, `torchvision:`/`callable:` strings, ...). classes / person_classes: the
    vehicle / person class names a target is matched with; class_map: a model's own class names -> "vehicle" |
    "person". class_names: a model's name (its column) -> its class names, by index (a list, or a YAML, JSON or
    text file holding them), for models that cannot give their own. conf: lowest confidence kept (low, so that a weak hit scores its confidence instead of 0). imgsz:
    network input size in pixels. device: auto | cpu | cuda (each entry's pick is in `devices`). threads: OpenVINO
    inference threads (0: its default; the detector's process sets it).
    """

    models: Sequence[str | Path]
    classes: Sequence[str] = ("car", "truck", "bus")
    conf: float = 0.05
    imgsz: int = 640
    device: str = "auto"
    threads: int = field(default=0, compare=False)
    person_classes: Sequence[str] = ("person",)
    class_map: Mapping[str, str] = field(default_factory=dict)
    class_names: Mapping[str, Any] = field(default_factory=dict)
    names: list[str] = field(init=False, compare=False)
    entries: list[Entry] = field(init=False, compare=False, repr=False)
    checked: bool = field(init=False, compare=False, repr=False, default=False)

    def __post_init__(self) -> None:
        if not self.models:
            raise GarageError("no detector models given", WHERE)
        if not 0.0 <= self.conf < 1.0:
            raise GarageError(f"conf {self.conf} is outside [0, 1)", "detector.conf")
        check_device(self.device)
        self.models = tuple(str(m) for m in self.models)
        self.classes = tuple(self.classes)
        self.person_classes = tuple(self.person_classes)
        self.class_map = dict(self.class_map or {})
        check_class_map(self.class_map)
        settings = EntrySettings(float(self.conf), int(self.imgsz), str(self.device), int(self.threads))
        # Each entry's kind is decided now (a missing file or an unknown format fails here); nothing is loaded.
        self.entries = [entry_kinds.make_entry(m, settings) for m in self.models]
        self.names = unique([e.name for e in self.entries])
        self.class_names = given_class_names(self.class_names, [e.name for e in self.entries])
        for entry in self.entries:
            entry.given_classes = tuple(self.class_names.get(entry.name, ()))

    def __reduce__(self):
        """Pickled as its settings: the other side makes its own entries (loaded models do not travel)."""
        return (_remade, ({f.name: getattr(self, f.name) for f in fields(self) if f.init},))

    @property
    def devices(self) -> list[str]:
        return [e.device for e in self.entries]

    def scoring(self) -> dict[str, tuple[str, ...]]:
        """`score_target`'s class groups: the listed classes plus the class map's."""
        mapped = {g: tuple(k for k, v in self.class_map.items() if v == g) for g in GROUPS}
        return {"classes": self.classes + tuple(c for c in mapped["vehicle"] if c not in self.classes),
                "person_classes": self.person_classes + tuple(c for c in mapped["person"]
                                                              if c not in self.person_classes)}

    def check(self, intrinsics: Lens | None = None) -> None:
        """Load every entry and run it on a probe frame of the camera `intrinsics` describes (the default camera
        without), then check the class names: GarageError naming the entry on the first problem."""
        for entry in self.entries:
            entry.check(intrinsics)
        self._check_classes()
        line = device_line(self.device, self.names, self.entries)
        if line not in _SAID:  # once per process and choice, not once per job
            _SAID[line] = True
            log.info("%s", line)
        self.checked = True

    def _check_classes(self) -> None:
        groups = self.scoring()
        wanted = set(groups["classes"]) | set(groups["person_classes"])
        known: set[str] = set()
        for entry in self.entries:
            if not entry.classes:  # every kind refuses a model whose names it cannot learn; defensive
                continue
            known |= set(entry.classes)
            if not wanted & set(entry.classes):
                shown = ", ".join(list(entry.classes)[:8]) + (", ..." if len(entry.classes) > 8 else "")
                raise GarageError(f"none of its classes ({shown}) is a vehicle or person class "
                                  f"({', '.join(sorted(wanted))}): map its names with detector.class_map, e.g. "
                                  f"+detector.class_map.{entry.classes[0]}=vehicle", entry.where)
        if not any(e.classes for e in self.entries):
            return
        unknown = sorted(set(self.class_map) - known)
        if unknown:
            raise GarageError(f"{unknown} are not among any model's classes", "detector.class_map")
        # A class the user listed that no model knows is a typo; the default (COCO) names may belong to no model.
        for key, listed, default in (("classes", self.classes, VEHICLE_CLASSES),
                                     ("person_classes", self.person_classes, PERSON_CLASSES)):
            unknown = sorted(set(listed) - known - set(default))
            if unknown:
                raise GarageError(f"classes {unknown} are not among any model's classes ({', '.join(self.names)})",
                                  f"detector.{key}")

    def detect(self, frames: Any, intrinsics: Lens | Sequence[Lens | None] | None = None
               ) -> list[list[Detections]]:
        """Every model's detections on each frame of the batch (frames: a list of HxWx3 uint8 RGB arrays, a
        (B, H, W, 3) array, or a (B, H, W, 3) uint8 torch tensor on any device; intrinsics: None, one camera for all, or one per frame): one list per frame, one
        `Detections` per model in `names` order. All classes are kept (non-target classes count as false
        positives)."""
        if not self.checked:
            self.check()
        batch = as_batch(frames)
        cams = per_frame(intrinsics, len(batch))
        out: list[list[Detections]] = [[] for _ in range(len(batch))]
        host = None  # a tensor batch copied to the host once, for the entries that take numpy frames
        for name, entry in zip(self.names, self.entries):
            start = time.perf_counter()
            if is_tensor(batch) and not entry.takes_tensors():
                host = on_host(batch) if host is None else host
                found = entry.detect(host, cams)
            else:
                found = entry.detect(batch, cams)
            ms = (time.perf_counter() - start) * 1000.0 / max(len(batch), 1)
            if len(found) != len(batch):
                raise GarageError(f"answered {len(found)} results for {len(batch)} frames", entry.where)
            for k, dets in enumerate(found):
                dets.model, dets.ms = name, ms
                out[k].append(dets)
        return out

    def cheap(self, scale: float) -> Detector:
        """The first model alone at `scale` of the input size (the search's pre-screen)."""
        first = self.entries[0].name
        return replace(self, models=self.models[:1], imgsz=max(160, int(round(self.imgsz * scale / 32)) * 32),
                       class_names={k: v for k, v in self.class_names.items() if k == first})


def _remade(settings: dict[str, Any]) -> Detector:
    return Detector(**settings)


def check_class_map(class_map: Mapping[str, str]) -> None:
    for name, group in class_map.items():
        if group not in GROUPS:
            raise GarageError(f"{name}: {group!r} is not vehicle or person", "detector.class_map")


def make_detector(*, models: Sequence[str], classes: Sequence[str] = ("car", "truck", "bus"),
                  person_classes: Sequence[str] = ("person",), class_map: Mapping[str, str] | None = None,
                  class_names: Mapping[str, Any] | None = None, conf: float = 0.05, imgsz: int = 640, device: str = "auto", name: str = "", iou: float = 0.5,
                  match: str = "full", threshold: float = 0.5, registry: str | None = None) -> Detector:
    """The default `detector._target_`, called with the `detector` group's keys: the composite `Detector`, model
    entries resolved (entries.resolve; `models:/` from the registry of the store `registry`), nothing loaded.
    name is the level's; iou, match and threshold are the scoring's (score_target)."""
    return Detector(models=[entry_kinds.resolve(m, registry) for m in models], classes=tuple(classes),
                    person_classes=tuple(person_classes), class_map=dict(class_map or {}),
                    class_names=dict(class_names or {}), conf=float(conf),
                    imgsz=int(imgsz), device=str(device))


def build_detector(conf: Any, **overrides: Any) -> Detector:
    """The detector a `detector` config node describes, through the one factory (`core.plugins.build` of its
    `_target_`); overrides replace the node's keys (the pre-screen's smaller input, the loop's one model)."""
    from garage_exp.core.plugins import build

    detector = build(conf, "a detector", "detector._target_", **overrides)
    if not isinstance(detector, Detector):
        raise GarageError(f"{type(detector).__name__} is not a garage_exp Detector (the detector's _target_ must "
                          "return one, as make_detector does)", "detector._target_")
    return detector


def check_detector(conf: Any) -> None:
    """The `detector` group's values (that each entry exists and loads is checked by the job's preflight)."""
    from garage_exp.core.plugins import check_target
    from garage_exp.perception.detect.matching import check_match

    check_target(str(conf._target_), "a detector", "detector._target_")
    if not conf.models:
        raise GarageError("no detector models given", WHERE)
    if not 0.0 <= float(conf.conf) < 1.0:
        raise GarageError(f"conf {conf.conf} is outside [0, 1)", "detector.conf")
    check_range(conf.imgsz, 32, 4096, "detector.imgsz")
    check_match(conf.match, conf.iou, conf.threshold)
    check_device(conf.device)
    check_class_map(dict(conf.get("class_map") or {}))
    given_class_names(conf.get("class_names") or {})


def given_class_names(given: Mapping[str, Any], models: Sequence[str] | None = None) -> dict[str, tuple[str, ...]]:
    """`detector.class_names` read: each model's names as a tuple (a file's read now, so that the detector's
    process gets plain data). GarageError naming the key for a value that is neither a list of names nor a
    readable file of them, and (models given) for a key that is no model's name."""
    out = {}
    for key, value in dict(given).items():
        where = f"detector.class_names.{key}"
        if models is not None and key not in models:
            raise GarageError(f"no model is named {key!r} (the models: {', '.join(models)})", where)
        names = read_names_file(str(value), where) if isinstance(value, (str, Path)) else value
        if isinstance(names, Mapping):
            names = index_mapping(names, where)
        if not isinstance(names, (list, tuple, Sequence)) or isinstance(names, str) or not names or not all(
                isinstance(n, str) and n for n in names):
            raise GarageError("give a list of class-name strings, by class index, or a file holding one", where)
        out[str(key)] = tuple(names)
    return out


def read_names_file(text: str, where: str) -> Any:
    """Class names from a file: YAML or JSON (a list, an {index: name} mapping, or either under a `names` key, as
    in an ultralytics dataset YAML), or plain text with one name a line."""
    import yaml

    path = Path(text).expanduser()
    if not path.is_file():
        raise GarageError(f"{text!r} is neither a list of class names nor a file of them", where)
    try:
        raw = path.read_text()
        value = yaml.safe_load(raw) if path.suffix in (".yaml", ".yml", ".json") else None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise GarageError(f"cannot read class names from {path}: {str(exc).splitlines()[0]}", where) from None
    if value is None:  # a text file: one name a line
        return [line.strip() for line in raw.splitlines() if line.strip()]
    return value.get("names") if isinstance(value, Mapping) and "names" in value else value


def index_mapping(names: Mapping, where: str) -> list[str]:
    """{0: 'person', 1: 'bicycle', ...} as a list by index; GarageError unless the keys are 0..N-1."""
    try:
        by_index = {int(k): v for k, v in names.items()}
    except (TypeError, ValueError):
        raise GarageError("a mapping of class names must be {index: name}", where) from None
    if sorted(by_index) != list(range(len(by_index))):
        raise GarageError(f"class indices {sorted(by_index)[:5]}... are not 0..{len(by_index) - 1}", where)
    return [by_index[k] for k in range(len(by_index))]


def unique(names: Iterable[str]) -> list[str]:
    """Model names become table columns: two models with one name get _2, _3 suffixes."""
    seen: dict[str, int] = {}
    out = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        out.append(name if seen[name] == 1 else f"{name}_{seen[name]}")
    return out
