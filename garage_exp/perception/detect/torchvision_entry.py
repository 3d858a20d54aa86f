"""`torchvision:ARCH:FILE`: a torchvision detection model (Faster R-CNN, RetinaNet, FCOS, SSD, SSDlite) built
with no downloaded weights and loaded from the user's state dict.

FILE (a path, or a name under the models dir) holds what `torch.save` wrote: the model's `state_dict()`, with
COCO's 91 categories (torchvision's own label order); or a dict {"state_dict": ..., "names": [...]} for a model
with its own classes, names indexed by label (index 0 is the background).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from garage_exp.core.errors import did_you_mean
from garage_exp.perception.detect.base import (LOADED, Detections, Entry, EntrySettings, checked,
                                               is_tensor, probe_frame)
from garage_exp.perception.detect.devices import pick_device
from garage_exp.perception.detect.kinds import register_entry_kind, resolve_path
from garage_exp.scene.lenses import Lens

PREFIX = "torchvision:"
ARCHS = ("fasterrcnn_resnet50_fpn", "fasterrcnn_resnet50_fpn_v2", "fasterrcnn_mobilenet_v3_large_fpn",
         "fasterrcnn_mobilenet_v3_large_320_fpn", "retinanet_resnet50_fpn", "retinanet_resnet50_fpn_v2",
         "fcos_resnet50_fpn", "ssd300_vgg16", "ssdlite320_mobilenet_v3_large")


def coco_names() -> list[str]:
    """torchvision's 91 COCO categories by label (0 the background, "N/A" for unused ids)."""
    from torchvision.models.detection import FasterRCNN_ResNet50_FPN_Weights

    return list(FasterRCNN_ResNet50_FPN_Weights.COCO_V1.meta["categories"])


def mismatch(expected: dict, given, shown: int = 2) -> str:
    """Why a state dict does not load, in one line: torch's own message spans a line per key, and its first line
    ("Error(s) in loading state_dict for FasterRCNN:") says nothing. Counts of missing, unexpected and mis-shaped
    keys with the first few of each; a mis-shaped class head says how many classes the file was trained for."""
    if not isinstance(given, dict):
        return f"it holds a {type(given).__name__}, not a state dict"
    missing = [k for k in expected if k not in given]
    unexpected = [k for k in given if k not in expected]
    shaped = [(k, tuple(getattr(given[k], "shape", ())), tuple(expected[k].shape)) for k in expected
              if k in given and tuple(getattr(given[k], "shape", ())) != tuple(expected[k].shape)]
    parts = []
    if missing:
        parts.append(f"{len(missing)} of its {len(expected)} keys missing ({', '.join(missing[:shown])}"
                     f"{', ...' if len(missing) > shown else ''})")
    if unexpected:
        parts.append(f"{len(unexpected)} keys it does not have ({', '.join(unexpected[:shown])}"
                     f"{', ...' if len(unexpected) > shown else ''})")
    if shaped:
        parts.append(f"{len(shaped)} of another shape (" + ", ".join(
            f"{k}: {list(a)} in the file, {list(b)} here" for k, a, b in shaped[:shown])
                     + (", ..." if len(shaped) > shown else "") + ")")
    if not parts:
        return ""
    if missing and len(missing) == len(expected):
        parts.append("no key in common: a state dict of another architecture")
    head = [a[0] for k, a, _ in shaped if k.endswith("box_predictor.cls_score.weight") and a]
    if head:  # Faster R-CNN's class head: the file was trained for this many classes, the background included
        parts.append(f"the file's model has {head[0]} classes: save it as {{'state_dict': ..., 'names': [...]}} with "
                     f"its {head[0]} names, the background first")
    return "; ".join(parts)


def concrete(entry: str) -> str:
    """torchvision:ARCH:FILE with FILE found as a model file is (left as written when it has no file part)."""
    arch, sep, file = entry[len(PREFIX):].partition(":")
    return f"{PREFIX}{arch}:{resolve_path(file)}" if sep and file else entry


@register_entry_kind("torchvision", prefix=PREFIX, resolve=concrete)
class TorchvisionEntry(Entry):
    kind = "torchvision"

    def __init__(self, entry: str, settings: EntrySettings):
        super().__init__(entry, settings)
        arch, sep, file = self.entry[len(PREFIX):].partition(":")
        if not sep or not file:
            raise self.fail("a torchvision entry is torchvision:ARCH:STATE_DICT_FILE")
        if arch not in ARCHS:
            raise self.fail(f"unknown architecture {arch!r}{did_you_mean(arch, ARCHS)} (one of {', '.join(ARCHS)})")
        self.arch = arch
        self.path = resolve_path(file)
        if not self.path.is_file():
            raise self.fail(f"state-dict file not found: {self.path}")
        self.name = Path(file).stem
        self.device = pick_device(settings.device)
        self._model = None
        self._labels: list[str] = []

    def check(self, intrinsics: Lens | None = None) -> None:
        if self._model is not None:
            return
        self._model, self._labels = LOADED.get(("torchvision", self.arch, self.path.resolve(), self.device),
                                               self._load)
        self.classes = tuple(dict.fromkeys(n for n in self._labels if n not in ("__background__", "N/A")))
        self.detect([probe_frame(intrinsics)], [intrinsics])

    def _load(self):
        import torch
        from torchvision.models import detection

        try:
            saved = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - pickles, zips, text: one line naming the entry
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise self.fail(f"not a torch state dict ({type(exc).__name__}: {first})"[:300]) from None
        if not isinstance(saved, dict):
            raise self.fail(f"holds a {type(saved).__name__}, not a state dict")
        state = saved.get("state_dict", saved)
        names = [str(n) for n in saved["names"]] if "names" in saved else coco_names()
        model = getattr(detection, self.arch)(weights=None, weights_backbone=None, num_classes=len(names))
        try:
            model.load_state_dict(state)
        except Exception as exc:  # noqa: BLE001 - missing or mis-shaped keys: the file is another model's
            why = mismatch(model.state_dict(), state) or (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise self.fail(f"its state dict does not fit {self.arch} with {len(names)} classes: {why}") from None
        # torchvision drops boxes under its own thresholds (up to 0.2 for FCOS): keep what the project keeps.
        for part in (model, getattr(model, "roi_heads", None)):
            if part is not None and hasattr(part, "score_thresh"):
                part.score_thresh = min(float(part.score_thresh), self.settings.conf)
        return model.eval().to(self.device), names

    def takes_tensors(self) -> bool:
        return True  # a torch model: a tensor batch goes in on its device

    def detect(self, frames: Sequence[np.ndarray], intrinsics: Sequence[Lens | None]) -> list[Detections]:
        import torch

        if is_tensor(frames):
            images = list(frames.to(self.device).permute(0, 3, 1, 2).float().div(255.0))  # `checked`: its shape
        else:
            images = [torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1).float().div(255.0).to(self.device)
                      for rgb in frames]
        with torch.inference_mode():
            results = self._model(images)
        out = []
        for rgb, result in zip(frames, results):
            scores = result["scores"].cpu().numpy().astype(np.float32)
            keep = scores >= self.settings.conf
            labels = result["labels"].cpu().numpy()[keep]
            names = [self._labels[k] if 0 <= k < len(self._labels) else f"class{k}" for k in labels]
            out.append(checked(Detections(result["boxes"].cpu().numpy().astype(np.float32)[keep], scores[keep],
                                          names), rgb, "its output"))
        return out
