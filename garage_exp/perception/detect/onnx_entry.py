"""An ONNX detection graph that ultralytics did not export, run through onnxruntime.

What the graph must look like (docs/perception.md): one image input, float32 RGB in [0, 1], NCHW (1, 3, H, W)
or CHW (3, H, W); a fixed H and W makes the frame resized to them (and the boxes scaled back), symbolic ones
take the frame as it is. Three outputs: boxes (N, 4) x1, y1, x2, y2 in the input's pixels, scores (N,) and
integer labels (N,), each optionally with a leading batch of 1 (torchvision's detection models export so).
Outputs are told apart by name (box, score or conf, label or class) or else by shape and type. The class names
are the graph's metadata `names` (a JSON list, or ultralytics' {0: 'person', ...}), indexed by label.
"""

from __future__ import annotations

import ast
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from garage_exp.core.state import STATE
from garage_exp.perception.detect.base import (LOADED, Detections, Entry, EntrySettings, checked,
                                               probe_frame)
from garage_exp.perception.detect.devices import pick_device
from garage_exp.perception.detect.kinds import register_entry_kind
from garage_exp.scene.lenses import Lens

ROLES = ("boxes", "scores", "labels")
NAME_HINTS = {"boxes": ("box", "bbox"), "scores": ("score", "conf"), "labels": ("label", "class", "cls")}


def onnx_metadata(path: str | Path) -> dict[str, str]:
    """The graph's metadata (key -> value), read without its external weights; {} for a file that is not ONNX."""
    return dict(_read(path)[1])


def onnx_unreadable(path: str | Path) -> str:
    """Why the file is not a readable ONNX model ("" when it is one): not protobuf, cut short, or no graph."""
    return _read(path)[0]


def _read(path: str | Path) -> tuple[str, tuple[tuple[str, str], ...]]:
    p = Path(path)
    try:
        stat = p.stat()
    except OSError as exc:
        return f"cannot read it ({exc.strerror})", ()
    return _parsed(str(p.resolve()), stat.st_mtime_ns, stat.st_size)


@STATE.memo("process", maxsize=64)
def _parsed(path: str, mtime: int, size: int) -> tuple[str, tuple[tuple[str, str], ...]]:
    """(why it is unreadable or "", its metadata), the file parsed once per version of it."""
    import onnx

    try:
        model = onnx.load(path, load_external_data=False)
    except Exception as exc:  # noqa: BLE001 - a text file, a truncated download: protobuf's DecodeError and kin
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        return f"it does not parse as ONNX ({first})"[:300], ()
    if not model.graph.node or not model.graph.output:  # a protobuf cut at a field boundary parses, emptied
        return "it holds no complete graph (no nodes or no outputs: a truncated or empty file?)", ()
    return "", tuple((p.key, p.value) for p in model.metadata_props)


def parse_names(text: str) -> list[str]:
    """`names` metadata: a JSON list, a JSON object or Python dict literal of index -> name."""
    try:
        value = json.loads(text)
    except ValueError:
        value = ast.literal_eval(text)
    if isinstance(value, dict):
        top = max(int(k) for k in value) if value else -1
        return [str(value.get(k, value.get(str(k), f"class{k}"))) for k in range(top + 1)]
    return [str(v) for v in value]


def is_ultralytics_onnx(entry: str) -> bool:
    """An ONNX file exported by ultralytics: its metadata names the exporter (checked without the weights); the
    ultralytics kind loads it."""
    return Path(entry).suffix == ".onnx" and "Ultralytics" in onnx_metadata(entry).get("author", "")


def other_onnx(entry: str) -> bool:
    return Path(entry).suffix == ".onnx" and Path(entry).is_file() and not is_ultralytics_onnx(entry)


@register_entry_kind("onnx", other_onnx, says="a .onnx file")
class OnnxEntry(Entry):
    kind = "onnx"

    def __init__(self, entry: str, settings: EntrySettings):
        super().__init__(entry, settings)
        self.path = Path(entry)
        self.name = self.path.stem
        self.device = pick_device(settings.device)
        self._session = None
        self._roles: dict[str, int] = {}
        self._labels: list[str] = []

    def check(self, intrinsics: Lens | None = None) -> None:
        if self._session is not None:
            return
        unreadable = onnx_unreadable(self.path)
        if unreadable:
            raise self.fail(f"not a readable ONNX model: {unreadable}")
        meta = onnx_metadata(self.path)
        if not meta.get("names") and self.given_classes:  # names given in the config (detector.class_names)
            meta["names"] = json.dumps(list(self.given_classes))
        if not meta.get("names"):
            raise self.fail("the ONNX graph has no `names` metadata (its class names, indexed by label; "
                            f"docs/perception.md shows how to add them, or give them: +detector.class_names."
                            f"{self.name}=[...])")
        try:
            self._labels = parse_names(meta["names"])
        except (ValueError, SyntaxError, TypeError):
            raise self.fail("its `names` metadata is neither a JSON list nor a {index: name} mapping") from None
        self.classes = tuple(dict.fromkeys(n for n in self._labels if n not in ("__background__", "N/A")))
        session = LOADED.get(("onnx", self.path.resolve(), self.device), self._load)
        self._roles = self._output_roles(session)
        self._session = session
        try:
            self.detect([probe_frame(intrinsics)], [intrinsics])
        except Exception as exc:  # noqa: BLE001 - a graph that cannot run on a frame: one line
            self._session = None
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise self.fail(f"on a probe frame: {first}"[:300]) from None

    def _load(self):
        import onnxruntime as ort

        wanted = ["CUDAExecutionProvider"] if self.device.startswith("cuda") else []
        providers = [p for p in wanted if p in ort.get_available_providers()] + ["CPUExecutionProvider"]
        if self.device.startswith("cuda") and providers[0] != "CUDAExecutionProvider":
            self.device = "cpu"  # onnxruntime without its CUDA provider: the CPU, as the device line says
        options = ort.SessionOptions()
        if self.settings.threads > 0:
            options.intra_op_num_threads = self.settings.threads
        try:
            return ort.InferenceSession(str(self.path), options, providers=providers)
        except Exception as exc:  # noqa: BLE001 - onnxruntime's errors are long; one line naming the entry
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise self.fail(f"onnxruntime cannot load it: {first}"[:300]) from None

    def _output_roles(self, session) -> dict[str, int]:
        """Which output is boxes, scores, labels; GarageError when the outputs are not detections."""
        outputs = session.get_outputs()
        inputs = session.get_inputs()
        shown = ", ".join(f"{o.name}{list(o.shape)}" for o in outputs)
        want = "want boxes (N, 4), scores (N,) and labels (N,), each optionally with a leading batch of 1"
        if len(inputs) != 1 or len(inputs[0].shape) not in (3, 4):
            raise self.fail(f"a detection graph has one image input (1, 3, H, W) or (3, H, W); this one has "
                            + ", ".join(f"{i.name}{list(i.shape)}" for i in inputs))
        if len(outputs) != 3:
            raise self.fail(f"its outputs ({shown}) are not detections: {want}")
        roles: dict[str, int] = {}
        for role in ROLES:
            named = [k for k, o in enumerate(outputs) if any(h in o.name.lower() for h in NAME_HINTS[role])]
            if len(named) == 1:
                roles[role] = named[0]
        if len(roles) < 3:  # by shape and type: boxes end in 4, labels are integers, scores are the rest
            roles = {}
            for k, o in enumerate(outputs):
                if o.shape and o.shape[-1] == 4 and len(o.shape) >= 2:
                    roles.setdefault("boxes", k)
                elif "int" in o.type:
                    roles.setdefault("labels", k)
                else:
                    roles.setdefault("scores", k)
        if sorted(roles) != sorted(ROLES) or len(set(roles.values())) != 3:
            raise self.fail(f"its outputs ({shown}) are not detections: {want}")
        box = outputs[roles["boxes"]].shape
        if len(box) not in (2, 3) or box[-1] != 4:
            raise self.fail(f"its boxes output {outputs[roles['boxes']].name}{list(box)} is not (N, 4): {want}")
        return roles

    def detect(self, frames: Sequence[np.ndarray], intrinsics: Sequence[Lens | None]) -> list[Detections]:
        import cv2

        session = self._session
        inp = session.get_inputs()[0]
        shape = inp.shape
        h_fixed, w_fixed = shape[-2], shape[-1]
        out = []
        for rgb in frames:
            h, w = rgb.shape[:2]
            size = (w_fixed, h_fixed) if isinstance(h_fixed, int) and isinstance(w_fixed, int) else (w, h)
            image = rgb if size == (w, h) else cv2.resize(rgb, size, interpolation=cv2.INTER_LINEAR)
            tensor = np.ascontiguousarray(image.transpose(2, 0, 1), dtype=np.float32) / 255.0
            if len(shape) == 4:
                tensor = tensor[None]
            arrays = session.run(None, {inp.name: tensor})
            boxes, scores, labels = (np.asarray(arrays[self._roles[r]]) for r in ROLES)
            boxes = boxes.reshape(-1, 4).astype(np.float32) * np.array([w / size[0], h / size[1]] * 2, np.float32)
            scores, labels = scores.reshape(-1).astype(np.float32), labels.reshape(-1).astype(np.int64)
            if not len(boxes) == len(scores) == len(labels):
                raise ValueError(f"its outputs hold {len(boxes)} boxes, {len(scores)} scores and {len(labels)} "
                                 "labels: not detections")
            keep = scores >= self.settings.conf
            names = [self._labels[k] if 0 <= k < len(self._labels) else f"class{k}" for k in labels[keep]]
            out.append(checked(Detections(boxes[keep], scores[keep], names), rgb, "its output"))
        return out
