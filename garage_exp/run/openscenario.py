"""`export.openscenario=true`: a job's scenario as OpenSCENARIO and its garage as OpenDRIVE
(garage_exp/exports/openscenario.py), from the scene the job's preflight built; the search and the suite export
the jobs they compose (their hardest trials, their scenarios) the same way, without rendering them."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from garage_exp.core.errors import GarageError


def check_export(cfg: DictConfig) -> None:
    if cfg.export.openscenario and cfg.dry_run:
        raise GarageError("a dry run builds no scenario to export; drop dry_run=true or export.openscenario=true",
                          "export.openscenario")


def export(cfg: DictConfig, out: Path, prepared=None) -> list[Path]:
    """`out`/garage.xodr and `out`/scenario.xosc (one .xosc per variant); `prepared`: the job's own preflight,
    else the job is prepared here (its plan, assets and scene; nothing rendered)."""
    from garage_exp.exports import openscenario

    if prepared is None:
        from garage_exp.run.preflight import preflight

        prepared = preflight(cfg, check_space=False)
    return openscenario.write(cfg, prepared.classified, prepared.setup, out)
