"""The entry kinds' registry: which kinds of entry `detector.models` may hold, each registered beside its `Entry`
class with `@register_entry_kind(NAME, claims=..., prefix=..., resolve=...)`.

A kind names a test on the entry (`claims`, given the resolved string, cheap: it loads nothing) and, for kinds named
by a prefix (`callable:`, `http://`), the prefix, so that such an entry is never looked up as a file. Kinds are
tried in registration order and the first that claims an entry makes it; the shipped kinds claim disjoint
entries, so the order they are imported in does not matter. An entry module imports torch, onnxruntime or
ultralytics only inside its methods: importing every kind's module to register it loads none of them.

Adding a kind is one module: its Entry class decorated here (docs/architecture.md, "Extension points"); the
shipped modules are imported by perception/detect/entries.py, which uses the registry, and a user's module by
whoever uses it before the detector is made.

Also here, for the kinds' own use: where a model file named in the config lies (`resolve_path`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from garage_exp.perception.detect.base import Entry, EntrySettings

OPENVINO_SUFFIX = "_openvino_model"


@dataclass(frozen=True)
class EntryKind:
    name: str
    claims: Callable[[str], bool]  # the resolved entry string -> whether this kind loads it (cheap, no loading)
    entry_class: type[Entry]
    prefix: str = ""  # a string prefix that names the kind ("callable:"); "" for files
    # a prefixed entry made concrete (its file part an absolute path: the detector's process may run elsewhere)
    resolve: Callable[[str], str] | None = None
    says: str = ""  # its entries in words, for messages ("a .onnx file"); "" says PREFIX...

    def make(self, entry: str, settings: EntrySettings) -> Entry:
        return self.entry_class(entry, settings)


KINDS: list[EntryKind] = []


def register_entry_kind(name: str, claims: Callable[[str], bool] = lambda entry: True, prefix: str = "",
                        resolve: Callable[[str], str] | None = None, says: str = "") -> Callable[[type], type]:
    """Register the decorated Entry class as the kind `name` (replacing a kind of that name): a file kind with its
    `claims`, or a kind named by its `prefix` (every entry that starts with it; `resolve` makes its file part
    concrete)."""
    def register(cls: type[Entry]) -> type[Entry]:
        kind = EntryKind(name, claims, cls, prefix, resolve, says or f"{prefix}...")
        KINDS[:] = [k for k in KINDS if k.name != name] + [kind]
        return cls
    return register


def prefixed(entry: str) -> EntryKind | None:
    """The kind whose prefix the entry starts with, if any."""
    return next((k for k in KINDS if k.prefix and str(entry).startswith(k.prefix)), None)


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
