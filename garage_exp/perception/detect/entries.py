"""The entry registry: which kind of `Entry` an entry of `detector.models` is, decided from its string or its
file without loading anything, and the entry made from it.

A kind registers once (`register`): its name, a test on the entry (`claims`, given the resolved string), the
dotted path of its `Entry` class (imported only when an entry of that kind is made, so that torch or
onnxruntime load only for the entries that need them), and, for kinds named by a prefix (`callable:`, `http://`),
the prefix, so that such an entry is never looked up as a file. Kinds are tried in registration order; the first
that claims the entry makes it. Adding a format is one module (its Entry) and one `register` call here.

Resolution (`resolve`) comes first: `models:/NAME/N` from the MLflow registry (a local `.pt`), a prefixed entry as
written (its file part resolved by the kind), a path as is when absolute or existing, else a name under the
models dir.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from garage_exp.core.errors import GarageError
from garage_exp.perception.detect.base import WHERE, Entry, EntrySettings

OPENVINO_SUFFIX = "_openvino_model"


@dataclass(frozen=True)
class EntryKind:
    name: str
    claims: Callable[[str], bool]  # the resolved entry string -> whether this kind loads it (cheap, no loading)
    entry_class: str  # "module:Class" of its Entry
    prefix: str = ""  # a string prefix that names the kind ("callable:"); "" for files
    # a prefixed entry made concrete (its file part an absolute path: the detector's process may run elsewhere)
    resolve: Callable[[str], str] | None = None

    def make(self, entry: str, settings: EntrySettings) -> Entry:
        module, _, name = self.entry_class.partition(":")
        return getattr(importlib.import_module(module), name)(entry, settings)


KINDS: list[EntryKind] = []


def register(kind: EntryKind) -> None:
    """Add (or replace, by name) an entry kind."""
    KINDS[:] = [k for k in KINDS if k.name != kind.name] + [kind]


def prefixed(entry: str) -> EntryKind | None:
    """The kind whose prefix the entry starts with, if any."""
    return next((k for k in KINDS if k.prefix and str(entry).startswith(k.prefix)), None)


def resolve(entry: str | Path, registry: str | None = None) -> str:
    """A config entry made concrete: `models:/NAME/VERSION` from the registry of the store `registry` (None: the
    default store), a prefixed entry as written, an absolute path or an existing relative path as is, else a name
    under the models dir."""
    from garage_exp.perception.detect import registry as model_registry

    text = str(entry)
    if model_registry.is_registered(text):
        return str(model_registry.resolve(text, registry))
    kind = prefixed(text)
    if kind is not None:
        return kind.resolve(text) if kind.resolve else text
    return str(resolve_path(text))


def resolve_path(text: str) -> Path:
    """A model file or folder: as is when absolute, made absolute when it exists relative to the working dir,
    else under the models dir (an OpenVINO export the models dir lacks falls back to the official `.pt` of the
    same network that `assets fetch` brings)."""
    path = Path(text).expanduser()
    if path.is_absolute() or path.exists():
        return path.absolute()
    from garage_exp.assets.locate import models_dir

    root = models_dir()
    found = root / path
    if not found.exists() and path.name.endswith(OPENVINO_SUFFIX):
        # INT8 exports need calibration data that is not fetched: yolo11n_int8_openvino_model -> yolo11n.pt.
        official = root / (path.name.split("_")[0] + ".pt")
        if official.exists():
            return official
    return found


def kind_of(entry: str) -> EntryKind:
    """The kind that loads a resolved entry; GarageError naming the entry when none does (a missing file says so,
    with a hint when a bare weights name would have been downloaded)."""
    kind = prefixed(entry)
    if kind is not None:
        return kind
    path = Path(entry)
    where = f"{WHERE} {entry}"
    if not path.exists():
        hint = " (a bare weights name would be downloaded from GitHub; give the path of a local file)" \
            if path.suffix == ".pt" and not path.is_absolute() and len(path.parts) == 1 else ""
        raise GarageError(f"model not found{hint}", where)
    for kind in KINDS:
        if not kind.prefix and kind.claims(entry):
            return kind
    if path.is_dir():
        raise GarageError(f"a model folder must be an OpenVINO export named *{OPENVINO_SUFFIX}", where)
    raise GarageError(f"unsupported model file; use {known()}", where)


def known() -> str:
    """The kinds users may write, for messages."""
    return ("a .pt, .onnx, .engine or .torchscript file, a *_openvino_model folder, models:/NAME/VERSION, "
            + ", ".join(f"{k.prefix}..." for k in KINDS if k.prefix))


def make_entry(entry: str, settings: EntrySettings) -> Entry:
    """The Entry for a resolved entry string (not loaded yet: `check()` loads it)."""
    return kind_of(entry).make(entry, settings)


# -- the kinds ---------------------------------------------------------------------------------------------------


def is_openvino_dir(entry: str) -> bool:
    path = Path(entry)
    return path.is_dir() and path.name.endswith(OPENVINO_SUFFIX)


def is_ultralytics_onnx(entry: str) -> bool:
    """An ONNX file exported by ultralytics: its metadata names the exporter (checked without the weights)."""
    from garage_exp.perception.detect.onnx_entry import onnx_metadata

    return Path(entry).suffix == ".onnx" and "Ultralytics" in onnx_metadata(entry).get("author", "")


def _ultralytics_file(entry: str) -> bool:
    path = Path(entry)
    if path.is_dir():
        return is_openvino_dir(entry)
    return path.suffix in (".pt", ".engine", ".torchscript") or is_ultralytics_onnx(entry)


register(EntryKind("ultralytics", _ultralytics_file, "garage_exp.perception.detect.ultralytics_entry:UltralyticsEntry"))
register(EntryKind("onnx", lambda e: Path(e).suffix == ".onnx" and Path(e).is_file(),
                   "garage_exp.perception.detect.onnx_entry:OnnxEntry"))
def _torchvision_file(entry: str) -> str:
    """torchvision:ARCH:FILE with FILE found as a model file is (left as written when it has no file part)."""
    arch, sep, file = entry[len("torchvision:"):].partition(":")
    return f"torchvision:{arch}:{resolve_path(file)}" if sep and file else entry


register(EntryKind("torchvision", lambda e: True, "garage_exp.perception.detect.torchvision_entry:TorchvisionEntry",
                   prefix="torchvision:", resolve=_torchvision_file))
register(EntryKind("callable", lambda e: True, "garage_exp.perception.detect.callable_entry:CallableEntry",
                   prefix="callable:"))
for _prefix in ("http://", "https://", "grpc://"):  # a model server (KServe v2 / Triton); grpc:// is refused in one line
    register(EntryKind(f"server {_prefix[:-3]}", lambda e: True, "garage_exp.perception.detect.server:ServerEntry",
                       prefix=_prefix))
