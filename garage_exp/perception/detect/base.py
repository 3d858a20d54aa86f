"""The detector interface: what every model under test (an *entry* of `detector.models`) gives back, and the
small contract an entry keeps. docs/perception.md is the user's version of this page.

Contract
- `Detections`: one model's detections on one frame: `boxes` (N, 4) float32 x1, y1, x2, y2 in the frame's pixels,
  `scores` (N,) float32 in [0, 1], `classes` N class names (the model's own names; `detector.class_map` says which
  are vehicles and people). `model` and `ms` are filled in by the composite.
- The camera a frame came from is its picture's lens (`scene.lenses.Lens`: `width`, `height`, `fx`, `fy`, `cx`,
  `cy`, the camera matrix `K`, `model` "pinhole" | "fisheye" | "cylindrical" | a registered lens, and the model's
  own parameters, a fisheye's `k` and `fov`); `scene.views.picture_lens(spec)` gives it for a scene camera.
- `Entry`: one model. `name` (its column in the frame table), `device` (where it runs: "cpu", "cuda:0", or the
  server's address), `classes` (its class names, known after `check()`; empty when it cannot say).
  `check(intrinsics)` loads the model and runs it once on a probe frame of that camera's size, raising a
  one-line `GarageError` naming the entry on any problem; a job calls it before it writes anything. `detect(frames,
  intrinsics)` takes a batch (a list of HxWx3 uint8 RGB arrays, or an (B, H, W, 3) array) and returns one
  `Detections` per frame, in order. An entry computes each frame's result from that frame alone.
- A batch may also be a torch tensor (B, H, W, 3) uint8 on any device (the GPU path's pictures, which stay on the
  GPU). An entry whose `takes_tensors()` is true gets it as it is (an ultralytics network run by torch, a
  torchvision model: letterboxed and normalised on that device); every other entry gets it copied to the host once.
- Entries are made from their config string by `entries.make_entry` (which kind is decided from the string or
  the file, without loading anything), and combined by `detector.Detector`, the composite every caller gets from
  the one factory (`detector.make_detector`, the `detector._target_`, built through `core.plugins.build`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE
from garage_exp.scene.lenses import Lens, Pinhole

WHERE = "detector.models"


@dataclass
class Detections:
    """One model's detections on one frame, in the frame's pixel coordinates."""

    boxes: np.ndarray  # (N, 4) float32 x1, y1, x2, y2
    scores: np.ndarray  # (N,) float32 confidences in [0, 1]
    classes: list[str]  # N class names, the model's own
    model: str = ""  # the entry's name (set by the composite)
    ms: float = 0.0  # wall-clock time of the model's call, per frame

    def __len__(self) -> int:
        return len(self.classes)

    @classmethod
    def empty(cls, model: str = "") -> Detections:
        return cls(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), [], model)


# The camera an entry's check probes when it is given none: the project's default size and vertical FOV.
DEFAULT_CAMERA = Pinhole.from_fovy(640, 480, 60.0)


@dataclass(frozen=True)
class EntrySettings:
    """The `detector` group's settings every entry gets: lowest confidence kept, network input size, device
    (auto | cpu | cuda), OpenVINO inference threads (0: its default)."""

    conf: float = 0.05
    imgsz: int = 640
    device: str = "auto"
    threads: int = 0


class Entry(ABC):
    """One model of the composite detector (see the module's contract)."""

    kind: ClassVar[str] = ""  # the registered kind: "ultralytics", "onnx", "torchvision", "callable", ...

    def __init__(self, entry: str, settings: EntrySettings):
        self.entry = str(entry)  # as written in detector.models (resolved: a path, a prefix string)
        self.settings = settings
        self.name = self.entry  # a short name; subclasses set a better one
        self.device = "cpu"
        self.classes: tuple[str, ...] = ()
        # its class names by index as the config gives them (detector.class_names), for a model that cannot say
        self.given_classes: tuple[str, ...] = ()

    @property
    def where(self) -> str:
        """The place a message names: the key and the entry."""
        return f"{WHERE} {self.entry}"

    def fail(self, what: str) -> GarageError:
        """A one-line GarageError naming this entry."""
        return GarageError(what.strip().splitlines()[0] if what.strip() else what, self.where)

    @abstractmethod
    def check(self, intrinsics: Lens | None = None) -> None:
        """Load the model (once per process) and run it on a probe frame; GarageError naming the entry."""

    @abstractmethod
    def detect(self, frames: Sequence[np.ndarray], intrinsics: Sequence[Lens | None]) -> list[Detections]:
        """One Detections per frame (frames: checked RGB uint8 arrays; intrinsics: one per frame)."""

    def device_note(self) -> str:
        """Why the entry runs where it does, for the detector's device line ("" when there is nothing to say)."""
        return ""

    def takes_tensors(self) -> bool:
        """Whether `detect` takes a torch (B, H, W, 3) uint8 batch as it is (else it gets numpy frames)."""
        return False


def message_of(exc: GarageError) -> str:
    """A GarageError's message without its place."""
    text = str(exc)
    return text[len(f"{exc.where}: "):] if exc.where and text.startswith(f"{exc.where}: ") else text


def is_tensor(frames: Any) -> bool:
    """A torch tensor (without importing torch where nobody made one)."""
    return type(frames).__module__.startswith("torch") and hasattr(frames, "device")


def on_host(frames: Any) -> list[np.ndarray]:
    """A batch as numpy frames: a tensor batch copied to the host once, anything else as `as_batch` gives it."""
    return list(frames.detach().cpu().numpy()) if is_tensor(frames) else as_batch(frames)


def as_batch(frames: Any) -> Any:
    """A batch of frames as a list of HxWx3 uint8 RGB arrays, or a torch (B, H, W, 3) uint8 tensor kept as it is;
    ValueError for anything else (a single frame too: wrap it in a list)."""
    if is_tensor(frames):
        if frames.ndim != 4 or frames.shape[-1] != 3 or str(frames.dtype) != "torch.uint8":
            raise ValueError(f"expected a (B, H, W, 3) uint8 tensor of RGB frames, got {frames.dtype} "
                             f"{tuple(frames.shape)}")
        return frames
    if isinstance(frames, np.ndarray):
        if frames.ndim != 4:
            raise ValueError(f"expected a batch of frames (B, H, W, 3), got an array of shape {frames.shape}")
        frames = list(frames)
    out = list(frames)
    for rgb in out:
        if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            got = f"{rgb.dtype} {rgb.shape}" if isinstance(rgb, np.ndarray) else type(rgb).__name__
            raise ValueError(f"expected HxWx3 uint8 RGB frames, got {got}")
    return out


def per_frame(intrinsics: Any, count: int) -> list[Lens | None]:
    """intrinsics as one entry per frame: None, one lens for the whole batch, or a sequence of them."""
    if intrinsics is None or isinstance(intrinsics, Lens):
        return [intrinsics] * count
    out = list(intrinsics)
    if len(out) != count:
        raise ValueError(f"{len(out)} intrinsics for {count} frames")
    return out


def probe_frame(intrinsics: Lens | None) -> np.ndarray:
    """The frame an entry's check runs on: mid grey at the camera's size (the default camera without one)."""
    cam = intrinsics or DEFAULT_CAMERA
    return np.full((int(cam.height), int(cam.width), 3), 114, np.uint8)


def checked(out: Any, frame: np.ndarray, what: str) -> Detections:
    """A model's answer for one frame as a float32 `Detections`; ValueError (one line saying what is wrong, `what`
    naming the answer) when it is not one: another type, mismatched lengths, scores outside [0, 1], boxes not
    x1 <= x2, y1 <= y2 or not finite."""
    if not isinstance(out, Detections):
        raise ValueError(f"{what} is {type(out).__name__}, not a garage_exp.perception.detect.Detections")
    boxes = np.asarray(out.boxes, dtype=np.float32)
    scores = np.asarray(out.scores, dtype=np.float32).reshape(-1)
    classes = [c for c in out.classes] if not isinstance(out.classes, str) else None
    if classes is None or not all(isinstance(c, str) for c in classes):
        raise ValueError(f"{what}.classes must be a list of class-name strings")
    if boxes.size == 0:
        boxes = boxes.reshape(0, 4)
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        raise ValueError(f"{what}.boxes has shape {boxes.shape}, not (N, 4) x1, y1, x2, y2")
    if not len(boxes) == len(scores) == len(classes):
        raise ValueError(f"{what} holds {len(boxes)} boxes, {len(scores)} scores and {len(classes)} classes")
    if not (np.isfinite(boxes).all() and np.isfinite(scores).all()):
        raise ValueError(f"{what} holds a box or score that is not finite")
    if len(scores) and (scores.min() < 0.0 or scores.max() > 1.0):
        raise ValueError(f"{what}.scores must lie in [0, 1] (got {scores.min():g}..{scores.max():g})")
    if len(boxes) and ((boxes[:, 2] < boxes[:, 0]).any() or (boxes[:, 3] < boxes[:, 1]).any()):
        raise ValueError(f"{what}.boxes must be x1, y1, x2, y2 with x1 <= x2 and y1 <= y2 (pixels)")
    h, w = frame.shape[:2]
    if len(boxes) and (boxes.max() > 4 * max(h, w) or (boxes[:, 2:] <= 1.5).all() and max(h, w) > 8):
        raise ValueError(f"{what}.boxes are not in the frame's pixels ({w}x{h}): normalised or out of range?")
    return Detections(boxes, scores, classes, out.model, out.ms)


@dataclass
class Loaded:
    """What a process has loaded, by key (each model is loaded and warmed up once per process)."""

    models: dict[Any, Any] = field(default_factory=dict)

    def get(self, key: Any, load) -> Any:
        if key not in self.models:
            self.models[key] = load()
        return self.models[key]


LOADED = Loaded(STATE.cache("perception.detect.loaded", "process"))
