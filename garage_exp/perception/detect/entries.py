"""Which kind of `Entry` an entry of `detector.models` is, decided from its string or its file without loading
anything, and the entry made from it.

The kinds are a registry (perception/detect/kinds.py): each kind registers beside its Entry class with
`@register_entry_kind`, in its own module; this module, which uses the registry, imports the shipped kinds'
modules so that none is missing (they load torch or onnxruntime only when an entry of theirs is checked).

Resolution (`resolve`) comes first: `models:/NAME/N` from the MLflow registry (a local `.pt`), a prefixed entry as
written (its file part resolved by the kind), a path as is when absolute or existing, else a name under the
models dir.
"""

from __future__ import annotations

from pathlib import Path

from garage_exp.core.errors import GarageError
from garage_exp.perception.detect import (callable_entry, onnx_entry, server, torchvision_entry,  # noqa: F401
                                          ultralytics_entry)  # the shipped kinds register on import
from garage_exp.perception.detect.base import WHERE, Entry, EntrySettings
from garage_exp.perception.detect.kinds import (KINDS, OPENVINO_SUFFIX, EntryKind, prefixed,  # noqa: F401
                                                register_entry_kind, resolve_path)


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
    return ", ".join([*(k.says for k in KINDS if not k.prefix), "models:/NAME/VERSION",
                      *(k.says for k in KINDS if k.prefix)])


def make_entry(entry: str, settings: EntrySettings) -> Entry:
    """The Entry for a resolved entry string (not loaded yet: `check()` loads it)."""
    return kind_of(entry).make(entry, settings)
