"""Detectors from MLflow's Model Registry: `models:/garage-detector/3` (or `/latest`) in `detector.models`.

`python -m garage_exp.train` registers each training's weights as a version whose source is the run's `weights/`
artifact folder (one `.pt`). Here a version is resolved to a local `.pt`, copied once into the cache as
`<name>_v<N>.pt`, so that the frame table's column says which version scored it. The store is the job's own
(`detector.registry`, which defaults to `tracking.uri`; then $MLFLOW_TRACKING_URI, then outputs/mlflow.db); this
module reads it with the mlflow library directly, below the tracking layer.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

from garage_exp.core.errors import GarageError, did_you_mean
from garage_exp.core.paths import OUTPUTS_DIR, cache_dir

PREFIX = "models:/"


def is_registered(entry) -> bool:
    return str(entry).startswith(PREFIX)


def store_uri(uri: str | None) -> str:
    """The tracking store a job uses (as garage_exp.tracking.runs.tracking_uri, which this layer cannot import)."""
    return uri or os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{OUTPUTS_DIR / 'mlflow.db'}"


def parse(entry: str, where: str) -> tuple[str, str]:
    parts = str(entry)[len(PREFIX):].strip("/").split("/")
    if len(parts) != 2 or not parts[0] or not (parts[1].isdigit() or parts[1] == "latest"):
        raise GarageError(f"{entry!r}: a registered model is models:/NAME/VERSION (a number or latest)", where)
    return parts[0], parts[1]


def resolve(entry: str, uri: str | None = None, where: str = "detector.models") -> Path:
    """The local `.pt` of a registered version; GarageError when the store, the name or the version is absent
    (nothing is created: a missing sqlite store is not made)."""
    name, version = parse(entry, where)
    uri = store_uri(uri)
    if uri.startswith("sqlite:///") and not Path(uri[len("sqlite:///"):].split("?")[0]).is_file():
        raise GarageError(f"{entry!r}: no MLflow store at {uri[len('sqlite:///'):]}, so no registered models", where)
    import mlflow
    from mlflow.exceptions import MlflowException

    client = mlflow.MlflowClient(tracking_uri=uri)
    try:
        versions = client.search_model_versions(f"name = '{name}'")
    except MlflowException as exc:
        raise GarageError(f"{entry!r}: cannot read the registry of {uri}: {str(exc).splitlines()[0]}", where) from None
    if not versions:
        known = [m.name for m in client.search_registered_models()]
        raise GarageError(f"{entry!r}: no registered model {name!r} in {uri}"
                          + (did_you_mean(name, known) if known else " (the registry is empty)"), where)
    by_number = {int(v.version): v for v in versions}
    number = max(by_number) if version == "latest" else int(version)
    if number not in by_number:
        raise GarageError(f"{entry!r}: {name!r} has no version {number} (have: "
                          f"{', '.join(str(n) for n in sorted(by_number))})", where)
    return local_copy(by_number[number], name, number, uri, where)


def local_copy(version, name: str, number: int, uri: str, where: str) -> Path:
    """The version's weights as `<cache>/registry/<store>/<name>_v<N>.pt` (copied once: versions never change)."""
    target = cache_dir() / "registry" / hashlib.sha1(uri.encode()).hexdigest()[:12] / f"{name}_v{number}.pt"
    if target.is_file():
        return target
    source = str(version.source)
    local = Path(source[len("file://"):] if source.startswith("file://") else source)
    if not local.exists():  # a remote artifact store: download the folder
        import tempfile

        import mlflow

        local = Path(mlflow.artifacts.download_artifacts(artifact_uri=source, dst_path=tempfile.mkdtemp()))
    weights = sorted(local.glob("*.pt")) if local.is_dir() else [local]
    if len(weights) != 1 or weights[0].suffix != ".pt":
        raise GarageError(f"models:/{name}/{number}: its source {source} holds no single .pt file", where)
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_suffix(".part")
    shutil.copyfile(weights[0], partial)
    partial.replace(target)  # atomic: a concurrent job never reads half a file
    return target
