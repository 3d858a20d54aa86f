"""A sweep of Hydra's basic sweeper checked before its first job: every job composed and preflighted (models last),
the disk space its jobs need. The main command's sweep callback runs it before anything is written; the loop runs
it on each of its protocol sweeps before its first step."""

from __future__ import annotations

import contextlib

from omegaconf import DictConfig, OmegaConf

from garage_exp.core.errors import GarageError

BASIC_SWEEPER = "hydra._internal.core_plugins.basic_sweeper.BasicSweeper"


def sweep_jobs(config: DictConfig) -> list[list[str]] | None:
    """The override lists of every job of a BasicSweeper sweep, in launch order (None for other sweepers)."""
    if OmegaConf.select(config, "hydra.sweeper._target_") != BASIC_SWEEPER:
        return None
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser

    loader = GlobalHydra.instance().config_loader()
    params = [f"{k}={v}" for k, v in (OmegaConf.select(config, "hydra.sweeper.params") or {}).items()]
    parser = OverridesParser.create(config_loader=loader)
    overrides = parser.parse_overrides(params + list(config.hydra.overrides.task))
    return [list(job) for batch in BasicSweeper.split_arguments(overrides, None) for job in batch]


def check_sweep(config: DictConfig) -> list[list[str]] | None:
    """Compose and preflight every job of the sweep before any of them runs: a typo in the 40th job's level
    or a plan the last case cannot use fails the sweep at once, with one line and nothing written, instead of
    hours into the night. Returns the jobs (None when the sweeper is not Hydra's basic one)."""
    jobs = sweep_jobs(config)
    if jobs is None:
        return None
    from hydra.core.global_hydra import GlobalHydra

    from garage_exp.run.diskspace import check_free
    from garage_exp.run.preflight import load_models, preflight, store_dir

    loader = GlobalHydra.instance().config_loader()
    prepared_jobs = []
    for k, job in enumerate(jobs):
        job_cfg = loader.load_sweep_config(config, job)  # Hydra's errors (unknown level, wrong type) raise here
        with in_job(k, job):
            prepared_jobs.append(preflight(job_cfg, check_space=False, load=False))  # no model loaded yet
    needs = [(p.bytes_out, p.bytes_store) for p in prepared_jobs]
    # What needs no model first: a sweep that cannot fit on the disk is refused before any model is loaded.
    check_free([(config.hydra.sweep.dir, sum(n[0] for n in needs)), (store_dir(config), sum(n[1] for n in needs))],
               f"the sweep ({len(jobs)} jobs)")
    for k, prepared in enumerate(prepared_jobs):  # each detector is loaded once per process (worker.open_detector)
        with in_job(k, jobs[k]):
            load_models(prepared)
    return jobs


@contextlib.contextmanager
def in_job(k: int, job: list[str]):
    """A job's refusal names the job of the sweep."""
    try:
        yield
    except GarageError as exc:
        shown = " ".join(o for o in job if not o.lstrip("+~").startswith("tracking."))
        raise GarageError(str(exc), f"sweep job {k} ({shown})") from None
