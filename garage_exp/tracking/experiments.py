"""An MLflow experiment of ours: found or created (by several workers at once), its tags and artifact place."""

from __future__ import annotations

import re
from pathlib import Path

from garage_exp.tracking.client import retry
from garage_exp.tracking.ui import experiment_tags


def artifact_location(uri: str | None, name: str) -> str | None:
    """Where a new experiment of a sqlite store keeps its artifacts: beside the database file. (MLflow's default
    is ./mlruns of whatever directory the first run happened to start in, so a store's artifacts would end up
    scattered, or inside a temporary dir that is later deleted.) None for other stores: the server decides."""
    if not uri or not uri.startswith("sqlite:///"):
        return None
    db = Path(uri[len("sqlite:///"):])
    return str(db.parent / "mlartifacts" / (re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "experiment"))


def experiment_id(mlc, name: str) -> str:
    """The id of the experiment `name`, created with our tags if missing (tags added to an older one)."""
    def get_or_create():
        exp = mlc.get_experiment_by_name(name)
        if exp is not None:
            for key, value in experiment_tags().items():  # an experiment made by an older version lacks them
                if key not in exp.tags:
                    mlc.set_experiment_tag(exp.experiment_id, key, value)
            return exp.experiment_id
        try:
            return mlc.create_experiment(name, artifact_location=artifact_location(
                getattr(mlc, "tracking_uri", None), name), tags=experiment_tags())
        except Exception:  # another worker created it first
            exp = mlc.get_experiment_by_name(name)
            if exp is None:
                raise
            return exp.experiment_id

    return retry(get_or_create)
