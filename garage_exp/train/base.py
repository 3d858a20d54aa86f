"""The base of a training: a `.pt` detector to fine-tune (a user's production model, the official weights, or a
registered `models:/garage-detector/N`), or a model YAML to train from scratch (`yolov8n.yaml`, which ultralytics
ships, or a file). Checked by loading it, before anything is written."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from garage_exp.core.errors import GarageError
from garage_exp.core.offline import prepare_offline


@dataclass
class Base:
    entry: str  # as given
    path: str  # what ultralytics loads: a local .pt, or a model YAML (a path or a name ultralytics ships)
    kind: str  # pt | yaml
    names: dict[int, str] | None  # a .pt's classes; None for a YAML (it takes the data's)


def load_base(entry: str, registry: str | None) -> Base:
    """The base, loaded once to check it; GarageError (naming `base`) when it is not a detector."""
    from garage_exp.perception.detect import registry as model_registry

    entry = str(entry)
    if model_registry.is_registered(entry):
        path = model_registry.resolve(entry, registry, where="base")
    else:
        path = Path(entry).expanduser()
    suffix = path.suffix.lower()
    if suffix == ".pt":
        if not path.is_file():
            hint = " (a bare weights name would be downloaded; give the path of a local file)" \
                if len(path.parts) == 1 else ""
            raise GarageError(f"base: .pt file not found{hint}", str(path))
        model = _load(str(path.absolute()), "base")
        return Base(entry, str(path.absolute()), "pt", {int(k): str(v) for k, v in model.names.items()})
    if suffix in (".yaml", ".yml"):
        # A file here, or a model YAML ultralytics ships (yolov8n.yaml, yolo11s.yaml): built, not downloaded.
        name = str(path.absolute()) if path.is_file() else entry
        _load(name, "base")
        return Base(entry, name, "yaml", None)
    raise GarageError(f"{entry!r} is neither a .pt detector, a model YAML nor models:/NAME/VERSION", "base")


def _load(name: str, where: str):
    prepare_offline()
    from ultralytics import YOLO

    try:
        model = YOLO(name)
    except Exception as exc:  # ultralytics and torch raise many types; one line naming the file
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise GarageError(f"{where}: not a detector ultralytics can load ({type(exc).__name__}: {first[:200]})",
                          name) from None
    if model.task != "detect":
        raise GarageError(f"{where}: a {model.task} model, not a detector", name)
    return model


def check_names(base: Base, names: dict[int, str]) -> None:
    """A `.pt` fine-tunes only on data with its own class map (the project's: COCO's 80 names by COCO id)."""
    if base.names is not None and base.names != names:
        differ = sorted(k for k in set(base.names) | set(names) if base.names.get(k) != names.get(k))
        k = differ[0]
        raise GarageError(f"base: its class map ({len(base.names)} classes) does not match the data's "
                          f"({len(names)}): class {k} is {base.names.get(k)!r} in the base, {names.get(k)!r} in "
                          "the data", base.path)
