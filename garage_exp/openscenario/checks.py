"""The `export` node: its schema, registered here as a config node (core/config_nodes.py), and its checks, at the
job's preflight."""

from __future__ import annotations

from dataclasses import dataclass

from garage_exp.core.config_nodes import register_node
from garage_exp.core.errors import GarageError
from garage_exp.openscenario.model import Track
from garage_exp.openscenario.v1_0 import check_tracks
from garage_exp.openscenario.xosc_write import VERSIONS


@dataclass
class ExportConf:
    """The `export` node's schema, beside its check (check_export), registered below it:
    formats a job writes beside its frames for other tools (garage_exp/exports)."""

    # openscenario/scenario.xosc (ASAM OpenSCENARIO 1.2: entities, initial positions, routes, speeds, triggers)
    # and openscenario/garage.xodr (the plan's driving lanes as ASAM OpenDRIVE); a search writes its hardest
    # trials', a suite each scenario's (docs/openscenario.md)
    openscenario: bool = False
    # "1.2"; or "1.0" for CARLA's ScenarioRunner (its reader takes 1.0 only): the ego marked type=ego_vehicle,
    # CARLA blueprints as vehicle names and pedestrian models, no expressions, no synchronised arrivals (a
    # timed start instead); a reversing ego cannot be said in it and is refused
    openscenario_version: str = "1.2"


register_node("export", ExportConf)


def check_export(export, dry_run: bool) -> None:
    """The `export` group: a dry run builds no scenario to write; a version is one we write."""
    if export.openscenario and dry_run:
        raise GarageError("a dry run builds no scenario to export; drop dry_run=true or export.openscenario=true",
                          "export.openscenario")
    if str(export.openscenario_version) not in VERSIONS:
        raise GarageError(f"{export.openscenario_version!r} is not a version we write (1.2, or 1.0 for CARLA's "
                          "ScenarioRunner)", "export.openscenario_version")


def check_version(version: str, setup) -> None:
    """Refuse, at the job's preflight, a scenario the export's version cannot say (check_tracks): the ego's
    first and last frame of each variant tell whether it reverses."""
    ego = next(e for e in setup.vehicles if e.name == "ego")
    for label in dict.fromkeys(s.label for s in setup.shots if s.replicate == 0):
        shots = [s for s in setup.shots if s.label == label and s.replicate == 0]
        check_tracks(version, label, [Track("ego", ego, shots[0].ego, shots[-1].ego, 1.0)])
