"""`export.openscenario=true`: a job's scenario as OpenSCENARIO and its garage as OpenDRIVE (garage_exp/openscenario
writes them), from the scene the job's preflight built. The search and the suite export the jobs they compose
(their hardest trials, their scenarios) the same way, without rendering them: this is the one step that may have
to prepare a job first, so it stays with the job."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig


def export(cfg: DictConfig, out: Path, prepared=None) -> list[Path]:
    """`out`/garage.xodr and `out`/scenario.xosc (one .xosc per variant); `prepared`: the job's own preflight,
    else the job is prepared here (its plan, assets and scene; nothing rendered). The exporter is handed the
    scene builder's settings (SceneSpec), the version and the plan's name."""
    from garage_exp.core.plain import settings
    from garage_exp.openscenario.export import write
    from garage_exp.openscenario.tracks import export_info, variants
    from garage_exp.run.spec import scene_spec

    if prepared is None:
        from garage_exp.run.preflight import preflight

        prepared = preflight(cfg, check_space=False, load=False)  # its scene only: no model loads for a file
    # the preflight's one conversion; a PreparedJob put together by hand (tests) has none: converted here
    config = prepared.config if prepared.config is not None else settings(cfg)
    job = prepared.spec.scene if prepared.spec is not None else scene_spec(config)
    return write(export_info(job, str(config.export.openscenario_version), str(config.plan.name)),
                 prepared.classified, variants(job, prepared.setup), out)
