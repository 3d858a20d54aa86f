"""Run several COCO-pretrained YOLO models on one RGB frame, offline.

Two weight formats are accepted, both loaded through ultralytics' `YOLO`:
- an OpenVINO export: a folder whose name ends in `_openvino_model` (ultralytics rejects other folder names),
  holding the `.xml`/`.bin` IR and `metadata.yaml`;
- PyTorch weights: an existing `.pt` file (official or fine-tuned), or a version of MLflow's Model Registry,
  `models:/garage-detector/N` (registry.py: copied once into the cache as a `.pt`).
A bare name such as "yolo11n.pt" that is not an existing file is refused: ultralytics would try to download it
from GitHub.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from garage_exp.core.errors import GarageError, check_range
from garage_exp.core.offline import prepare_offline

log = logging.getLogger("garage_exp")
OPENVINO_SUFFIX = "_openvino_model"
DEVICES = ("auto", "cpu", "cuda")
_LOADED: dict[tuple[Path, int, str], Any] = {}  # (resolved path, threads, device) -> warmed-up YOLO: loaded once
_SAID: set[str] = set()  # device picks already logged by this process


@dataclass
class ModelDetections:
    """One model's detections on one frame, in the frame's pixel coordinates."""

    model: str  # short model name, e.g. "yolo11n_int8"
    boxes: np.ndarray  # (N, 4) float32 x1, y1, x2, y2
    confs: np.ndarray  # (N,) float32
    classes: list[str]  # N COCO class names
    ms: float = 0.0  # wall-clock time of this model's predict call

    def __len__(self) -> int:
        return len(self.classes)


def model_format(path: Path) -> str:
    """The weights format of a model path ("openvino" or "pt"); GarageError when it cannot be loaded offline."""
    where = str(path)
    if not path.exists():
        hint = " (a bare weights name would be downloaded from GitHub; give the path of a local file)" \
            if path.suffix == ".pt" and not path.is_absolute() and len(path.parts) == 1 else ""
        raise GarageError(f"model not found{hint}", where)
    if path.is_dir():
        if not path.name.endswith(OPENVINO_SUFFIX):
            raise GarageError(f"a model folder must be an OpenVINO export named *{OPENVINO_SUFFIX}", where)
        if not any(path.glob("*.xml")):
            raise GarageError("OpenVINO model folder holds no .xml file", where)
        return "openvino"
    if path.suffix == ".pt":
        return "pt"
    raise GarageError(f"unsupported model file; use a *{OPENVINO_SUFFIX} folder or a .pt file", where)


def model_label(path: Path) -> str:
    """A short name for tables and metrics: the folder name without the export suffix, or the file stem."""
    name = path.name
    if name.endswith(OPENVINO_SUFFIX):
        return name[: -len(OPENVINO_SUFFIX)]
    return path.stem


def resolve_model(entry: str | Path, registry: str | None = None) -> Path:
    """A config entry: `models:/NAME/VERSION` from the registry of the store `registry` (None: the default
    store), an absolute path or an existing relative path as is, else a name under the models dir."""
    from garage_exp.perception.detect import registry as model_registry

    if model_registry.is_registered(entry):
        return model_registry.resolve(str(entry), registry)
    path = Path(entry).expanduser()
    if path.is_absolute() or path.exists():
        return path
    from garage_exp.assets.locate import models_dir

    root = models_dir()
    found = root / path
    if not found.exists() and path.name.endswith("_openvino_model"):
        # `python -m garage_exp.assets fetch` brings the official .pt weights of the same network (INT8
        # exports need calibration data that is not fetched): yolo11n_int8_openvino_model -> yolo11n.pt.
        official = root / (path.name.split("_")[0] + ".pt")
        if official.exists():
            return official
    return found


def cuda_available() -> bool:
    """Whether torch sees a CUDA GPU (False when torch cannot even be imported)."""
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # noqa: BLE001 - a broken CUDA install means: no CUDA
        return False


def check_device(device: object) -> None:
    """`detector.device`: auto | cpu | cuda, and cuda only where torch sees a CUDA GPU."""
    if device not in DEVICES:
        raise GarageError(f"unknown device {device!r} (auto | cpu | cuda)", "detector.device")
    if device == "cuda" and not cuda_available():
        raise GarageError("cuda asked, but torch sees no CUDA GPU (torch.cuda.is_available() is False); "
                          "use auto or cpu", "detector.device")


def pick_device(device: str, kind: str) -> str:
    """The torch device string one model runs on: `device` (auto | cpu | cuda) for a model of format `kind`.

    OpenVINO exports (the INT8 COCO models) run on OpenVINO's CPU plugin whatever is asked: ultralytics runs
    OpenVINO on the CPU. A .pt model runs on "cuda:0" for cuda, and for auto when torch sees a CUDA GPU.
    """
    check_device(device)
    if device == "cpu" or kind == "openvino":
        return "cpu"
    if device == "cuda":
        return "cuda:0"
    return "cuda:0" if cuda_available() else "cpu"


def device_line(device: str, labels: Sequence[str], kinds: Sequence[str], picks: Sequence[str]) -> str:
    """One log line saying where each model runs and why, e.g.
    "detector device auto -> cpu for yolo11n_int8 (OpenVINO export: CPU only); cuda:0 for yolo11n"."""
    groups: dict[tuple[str, str], list[str]] = {}
    for label, kind, pick in zip(labels, kinds, picks):
        if kind == "openvino" and device != "cpu":
            why = " (OpenVINO export: CPU only)"
        elif pick == "cpu" and device == "auto":
            why = " (torch sees no CUDA GPU)"
        else:
            why = ""
        groups.setdefault((pick, why), []).append(label)
    return f"detector device {device} -> " + "; ".join(
        f"{pick} for {', '.join(names)}{why}" for (pick, why), names in groups.items())


def load_model(path: Path, imgsz: int = 640, device: str = "cpu", threads: int = 0) -> Any:
    """The ultralytics model for a path, loaded and warmed up once per process.

    threads > 0 caps OpenVINO's inference threads (0: OpenVINO's default, all cores). With rendering running
    beside detection on a small machine, one thread each wastes less CPU than two each fighting for the same
    cores (docs/performance.md). Ignored for .pt weights.
    """
    path = path.resolve()
    key = (path, threads, device)
    if key in _LOADED:
        return _LOADED[key]
    kind = model_format(path)
    prepare_offline()
    from ultralytics import YOLO

    start = time.perf_counter()
    try:
        # task="detect" spares ultralytics a guess from the file and a warning; harmless for .pt weights.
        model = YOLO(str(path), task="detect")
        # The first predict compiles the OpenVINO network (seconds); pay it here, not in the first frame.
        with _openvino_threads(threads if kind == "openvino" else 0):
            model.predict(np.zeros((imgsz, imgsz, 3), np.uint8), imgsz=imgsz, device=device, verbose=False)
    except GarageError:
        raise
    except Exception as exc:  # ultralytics raises many types; the user needs one line naming the model
        raise GarageError(f"cannot load {kind} model: {type(exc).__name__}: {exc}".splitlines()[0], str(path)) \
            from exc
    if threads > 0 and kind == "openvino" and _openvino_thread_count(model) not in (threads, None):
        log.warning("could not limit OpenVINO to %d threads for %s (ultralytics changed how it compiles)",
                    threads, path.name)
    log.info("loaded %s model %s in %.1f s", kind, path.name, time.perf_counter() - start)
    _LOADED[key] = model
    return model


@contextmanager
def _openvino_threads(threads: int):
    """Within this block, OpenVINO networks compile with INFERENCE_NUM_THREADS = threads (0: unchanged).

    ultralytics compiles with {"PERFORMANCE_HINT": "LATENCY"} and no thread setting, and an ov.Core's
    properties belong to that Core, which ultralytics makes itself; so the setting is added to every
    compile_model call made here. ultralytics keeps the bound method for later recompiles, which keep it too.
    Compiling twice instead (ultralytics', then ours) cost 1.5 s more per process.
    """
    if threads <= 0:
        yield
        return
    import openvino as ov

    original = ov.Core.compile_model

    def compile_model(core, model, device_name=None, config=None, **kwargs):
        return original(core, model, device_name, {**(config or {}), "INFERENCE_NUM_THREADS": threads}, **kwargs)

    ov.Core.compile_model = compile_model
    try:
        yield
    finally:
        ov.Core.compile_model = original


def _openvino_thread_count(model: Any) -> int | None:
    """INFERENCE_NUM_THREADS of a loaded OpenVINO model, None when ultralytics' layout hides it."""
    backend = getattr(getattr(getattr(model, "predictor", None), "model", None), "backend", None)
    try:
        return int(backend.ov_compiled_model.get_property("INFERENCE_NUM_THREADS"))
    except Exception:  # noqa: BLE001 - only a check
        return None


@dataclass
class Detector:
    """Several YOLO models run one after another on each frame.

    models: OpenVINO folders or .pt files (must exist). classes: the vehicle classes a vehicle target may be
    matched with; person_classes: those of a person target. conf: lowest confidence kept (low, so that a weak
    hit scores its confidence instead of 0). imgsz: network input size in pixels. device: auto | cpu | cuda
    (`pick_device`, per model; `devices` holds the picks). threads: OpenVINO inference threads (0: its default).
    """

    models: Sequence[str | Path]
    classes: Sequence[str] = ("car", "truck", "bus")
    conf: float = 0.05
    imgsz: int = 640
    device: str = "auto"
    threads: int = 0
    person_classes: Sequence[str] = ("person",)
    names: list[str] = field(init=False)
    paths: list[Path] = field(init=False)
    devices: list[str] = field(init=False)
    _models: list[Any] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.models:
            raise GarageError("no detector models given", "detector.models")
        if not 0.0 <= self.conf < 1.0:
            raise GarageError(f"conf {self.conf} is outside [0, 1)", "detector.conf")
        self.paths = [Path(m).expanduser() for m in self.models]
        kinds = [model_format(p) for p in self.paths]  # fail on a bad path before spending seconds loading
        self.devices = [pick_device(self.device, kind) for kind in kinds]
        self.classes = tuple(self.classes)
        self.person_classes = tuple(self.person_classes)
        self.names = _unique([model_label(p) for p in self.paths])
        line = device_line(self.device, self.names, kinds, self.devices)
        if line not in _SAID:  # once per process and choice, not once per job
            _SAID.add(line)
            log.info("%s", line)
        self._models = [load_model(p, self.imgsz, d, self.threads) for p, d in zip(self.paths, self.devices)]
        for path, model in zip(self.paths, self._models):
            for key, wanted in (("classes", self.classes), ("person_classes", self.person_classes)):
                unknown = set(wanted) - set(model.names.values())
                if unknown:
                    raise GarageError(f"classes {sorted(unknown)} are not among {path.name}'s classes",
                                      f"detector.{key}")

    @classmethod
    def from_config(cls, conf: Any, threads: int = 0) -> Detector:
        """From a `DetectorConf` (Hydra node): model entries resolved against the models dir."""
        from garage_exp.core.plugins import build

        return cls(**build(conf, "a detector", "detector._target_"), threads=threads)

    def detect(self, rgb: np.ndarray) -> list[ModelDetections]:
        """All classes' detections per model (non-vehicle classes are kept: they count as false positives)."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"expected an HxWx3 uint8 RGB frame, got {rgb.dtype} {rgb.shape}")
        bgr = np.ascontiguousarray(rgb[..., ::-1])  # ultralytics reads numpy images as OpenCV BGR
        out = []
        # Preprocessing (letterbox, scaling) is repeated per model, but it is ~2-3 ms of a 20-45 ms call:
        # sharing it would mean driving ultralytics' predictor internals, not worth the fragility.
        for name, model, device in zip(self.names, self._models, self.devices):
            start = time.perf_counter()
            result = model.predict(bgr, conf=self.conf, imgsz=self.imgsz, device=device, verbose=False)[0]
            ms = (time.perf_counter() - start) * 1000.0
            boxes = result.boxes
            out.append(ModelDetections(
                model=name,
                boxes=boxes.xyxy.cpu().numpy().astype(np.float32).reshape(-1, 4),
                confs=boxes.conf.cpu().numpy().astype(np.float32).reshape(-1),
                classes=[result.names[int(k)] for k in boxes.cls.cpu().numpy()],
                ms=ms,
            ))
        return out


def check_detector(conf: Any) -> None:
    """The `detector` group's values (that the weights exist is checked by `model_format(resolve_model(m))`)."""
    from garage_exp.core.plugins import check_target
    from garage_exp.perception.detect.matching import check_match

    check_target(str(conf._target_), "a detector", "detector._target_")
    if not conf.models:
        raise GarageError("no detector models given", "detector.models")
    if not 0.0 <= float(conf.conf) < 1.0:
        raise GarageError(f"conf {conf.conf} is outside [0, 1)", "detector.conf")
    check_range(conf.imgsz, 32, 4096, "detector.imgsz")
    check_match(conf.match, conf.iou, conf.threshold)
    check_device(conf.device)


def detector_spec(*, models: Sequence[str], classes: Sequence[str] = ("car", "truck", "bus"),
                  person_classes: Sequence[str] = ("person",), conf: float = 0.05, imgsz: int = 640,
                  device: str = "auto", name: str = "", iou: float = 0.5, match: str = "full",
                  threshold: float = 0.5, registry: str | None = None) -> dict[str, Any]:
    """The default `detector._target_`, called with the `detector` group's keys: the `Detector` arguments as
    plain picklable values (the detector's child process builds it from them), model entries resolved against
    the models dir (`models:/` entries from the registry of the store `registry`). name is the level's; iou, match
    and threshold are the scoring's (score_target)."""
    return {"models": [resolve_model(m, registry) for m in models], "classes": tuple(classes),
            "person_classes": tuple(person_classes), "conf": float(conf), "imgsz": int(imgsz), "device": str(device)}


def _unique(names: Iterable[str]) -> list[str]:
    """Model names become table columns: two models with one name get _2, _3 suffixes."""
    seen: dict[str, int] = {}
    out = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        out.append(name if seen[name] == 1 else f"{name}_{seen[name]}")
    return out
