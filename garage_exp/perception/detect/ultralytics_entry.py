"""Models ultralytics loads: `.pt` weights (YOLO or RT-DETR, official or fine-tuned), OpenVINO exports (a folder
named `*_openvino_model` holding the `.xml`/`.bin` IR and `metadata.yaml`), ONNX files ultralytics exported,
TensorRT engines (`.engine`, CUDA only) and TorchScript files (`.torchscript`).

A bare name such as "yolo11n.pt" that is not an existing file never gets here: ultralytics would download it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.core.environment import prepare_environment
from garage_exp.core.logfile import FILE_LOG
from garage_exp.perception.detect.base import LOADED, Detections, Entry, EntrySettings, is_tensor
from garage_exp.perception.detect.devices import cuda_available, pick_device
from garage_exp.perception.detect.kinds import OPENVINO_SUFFIX, register_entry_kind
from garage_exp.perception.detect.onnx_entry import is_ultralytics_onnx
from garage_exp.perception.detect.tensors import PAD_VALUE, Letterbox
from garage_exp.scene.lenses import Lens

log = logging.getLogger("garage_exp")
FORMATS = {".pt": "pt", ".onnx": "onnx", ".engine": "engine", ".torchscript": "torchscript"}
TORCH_FORMATS = ("pt", "torchscript", "engine")  # run by torch (or TensorRT on CUDA memory): fed tensors as they are
STRIDE = 32  # the YOLO and RT-DETR networks' largest stride: an input's sides are its multiples


def model_label(path: Path) -> str:
    """A short name for tables and metrics: the folder name without the export suffix, or the file stem."""
    name = path.name
    if name.endswith(OPENVINO_SUFFIX):
        return name[: -len(OPENVINO_SUFFIX)]
    return path.stem


def model_format(path: Path) -> str:
    """openvino | pt | onnx | engine | torchscript."""
    return "openvino" if path.is_dir() else FORMATS[path.suffix]


def is_openvino_dir(entry: str) -> bool:
    path = Path(entry)
    return path.is_dir() and path.name.endswith(OPENVINO_SUFFIX)


def ultralytics_file(entry: str) -> bool:
    """A file or folder ultralytics loads: weights, a TensorRT engine, TorchScript, an OpenVINO export folder or
    an ONNX file ultralytics exported."""
    path = Path(entry)
    if path.is_dir():
        return is_openvino_dir(entry)
    return path.suffix in (".pt", ".engine", ".torchscript") or is_ultralytics_onnx(entry)


@register_entry_kind("ultralytics", ultralytics_file,
                     says=f"a .pt, .engine or .torchscript file, a *{OPENVINO_SUFFIX} folder")
class UltralyticsEntry(Entry):
    kind = "ultralytics"

    def __init__(self, entry: str, settings: EntrySettings):
        super().__init__(entry, settings)
        self.path = Path(entry).expanduser()
        self.format = model_format(self.path)
        self.name = model_label(self.path)
        self.device = pick_device(settings.device, cpu_only=self.format == "openvino")
        self._model: Any = None

    def device_note(self) -> str:
        return "OpenVINO export: CPU only" if self.format == "openvino" and self.settings.device != "cpu" else ""

    def check(self, intrinsics: Lens | None = None) -> None:
        if self._model is not None:
            return
        if self.format == "openvino" and not any(self.path.glob("*.xml")):
            raise self.fail("OpenVINO model folder holds no .xml file")
        if self.format == "engine" and not cuda_available():
            raise self.fail("a TensorRT engine runs on a CUDA GPU, and torch sees none (export the model to ONNX "
                            "or OpenVINO to test it here)")
        s = self.settings
        self._model = LOADED.get((self.path.resolve(), s.threads, self.device),
                                 lambda: load_model(self.path, s.imgsz, self.device, s.threads, self.where))
        self.classes = tuple(str(v) for v in self._model.names.values())

    def takes_tensors(self) -> bool:
        return self.format in TORCH_FORMATS

    def detect(self, frames: Sequence[np.ndarray], intrinsics: Sequence[Lens | None]) -> list[Detections]:
        if is_tensor(frames):
            return self._detect_tensor(frames)
        # ultralytics reads numpy images as OpenCV BGR. One frame goes in as an array (as before batches), so a
        # batch of one gives the same numbers as the single-frame call the golden tables were measured with.
        bgr = [np.ascontiguousarray(rgb[..., ::-1]) for rgb in frames]
        s = self.settings
        results = self._model.predict(bgr[0] if len(bgr) == 1 else bgr, conf=s.conf, imgsz=s.imgsz,
                                      device=self.device, verbose=False)
        return [detections(result) for result in results]

    def _detect_tensor(self, frames) -> list[Detections]:
        """A (B, H, W, 3) uint8 RGB tensor batch, on its way to the network without leaving the device: letterboxed
        there as ultralytics letterboxes a numpy frame for a torch model (scaled to fit imgsz, then padded with grey
        to the stride's multiple, centred), as floats in [0, 1]; the boxes mapped back to the frame's pixels.
        Only the detections' numbers leave the device."""
        s = self.settings
        # a .pt network takes any multiple of the stride; an exported one (TorchScript, TensorRT) its fixed square
        x, box = letterbox_tensor(frames.to(self.device), s.imgsz, STRIDE, square=self.format != "pt")
        results = self._model.predict(x, conf=s.conf, imgsz=s.imgsz, device=self.device, verbose=False)
        h, w = int(frames.shape[1]), int(frames.shape[2])
        out = []
        for result in results:
            dets = detections(result)
            dets.boxes = box.unmap(dets.boxes, w, h)
            out.append(dets)
        return out


def detections(result) -> Detections:
    """An ultralytics result's boxes as `Detections` (the model's class names)."""
    boxes = result.boxes
    return Detections(boxes=boxes.xyxy.cpu().numpy().astype(np.float32).reshape(-1, 4),
                      scores=boxes.conf.cpu().numpy().astype(np.float32).reshape(-1),
                      classes=[result.names[int(k)] for k in boxes.cls.cpu().numpy()])


def letterbox_tensor(frames, imgsz: int, stride: int, square: bool = False):
    """(B, H, W, 3) uint8 -> ((B, 3, H', W') float32 in [0, 1], its `tensors.Letterbox`): scaled by
    min(imgsz / H, imgsz / W) (bilinear, as OpenCV's INTER_LINEAR), padded with 114 grey to a multiple of `stride`
    each way (ultralytics' LetterBox(auto=True), a .pt model's) or to imgsz x imgsz (`square`: an export's fixed
    input), centred as ultralytics centres it."""
    import torch.nn.functional as F

    b, h, w, _ = frames.shape
    gain = min(imgsz / h, imgsz / w)
    new_h, new_w = int(round(h * gain)), int(round(w * gain))
    x = frames.permute(0, 3, 1, 2).float()
    if (new_h, new_w) != (h, w):
        x = F.interpolate(x, size=(new_h, new_w), mode="bilinear", align_corners=False)
    dh, dw = ((imgsz - new_h) / 2, (imgsz - new_w) / 2) if square else (((-new_h) % stride) / 2, ((-new_w) % stride) / 2)
    top, bottom = int(round(dh - 0.1)), int(round(dh + 0.1))
    left, right = int(round(dw - 0.1)), int(round(dw + 0.1))
    x = F.pad(x, (left, right, top, bottom), value=float(PAD_VALUE))
    return x.div_(255.0), Letterbox(gain if (new_h, new_w) != (h, w) else 1.0, left, top)


def load_model(path: Path, imgsz: int = 640, device: str = "cpu", threads: int = 0, where: str | None = None) -> Any:
    """The ultralytics model for a path, loaded and warmed up (the caller keeps it: base.LOADED).

    threads > 0 caps OpenVINO's inference threads (0: OpenVINO's default, all cores). With rendering running
    beside detection on a small machine, one thread each wastes less CPU than two each fighting for the same
    cores (docs/performance.md). Ignored for other formats.
    """
    kind = model_format(path)
    prepare_environment(offline=True)
    from ultralytics import YOLO

    start = time.perf_counter()
    try:
        # task="detect" spares ultralytics a guess from the file and a warning; harmless for .pt weights.
        with quiet_ultralytics():  # "Loading ... for OpenVINO inference": the log file's, not the terminal's
            model = YOLO(str(path), task="detect")
            if getattr(model, "task", "detect") != "detect":
                raise GarageError(f"a {model.task} model, not a detector", where or str(path))
            # The first predict compiles the OpenVINO network (seconds); pay it here, not in the first frame.
            with _openvino_threads(threads if kind == "openvino" else 0):
                model.predict(np.zeros((imgsz, imgsz, 3), np.uint8), imgsz=imgsz, device=device, verbose=False)
    except GarageError:
        raise
    except Exception as exc:  # ultralytics raises many types; the user needs one line naming the model
        first = (str(exc).strip().splitlines() or [""])[0]
        raise GarageError(f"cannot load {kind} model: {type(exc).__name__}: {first}"[:300],
                          where or str(path)) from None
    if threads > 0 and kind == "openvino" and _openvino_thread_count(model) not in (threads, None):
        log.warning("could not limit OpenVINO to %d threads for %s (ultralytics changed how it compiles)",
                    threads, path.name)
    FILE_LOG.info("loaded %s model %s in %.1f s", kind, path.name, time.perf_counter() - start)
    return model


class _Relay(logging.Handler):
    """ultralytics' info lines to the log file (core.logfile); its warnings still reach the terminal."""

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno < logging.WARNING:
            FILE_LOG.log(record.levelno, "%s", record.getMessage().strip())


@contextmanager
def quiet_ultralytics():
    """Within this block ultralytics' info lines go to the log file, not to stdout."""
    from ultralytics.utils import LOGGER

    saved = [(h, h.level) for h in LOGGER.handlers]
    relay = _Relay()
    for handler, _ in saved:
        handler.setLevel(max(handler.level, logging.WARNING))
    LOGGER.addHandler(relay)
    try:
        yield
    finally:
        LOGGER.removeHandler(relay)
        for handler, level in saved:
            handler.setLevel(level)


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
