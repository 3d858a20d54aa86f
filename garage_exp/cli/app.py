"""The Hydra application: the entry point (`main`) and the command line (`cli`).

Bad input never costs a run: the job (garage_exp.run.job) checks its inputs first (garage_exp.run.preflight), a sweep
checks all its jobs before the first starts (garage_exp.cli.callbacks), and every input error becomes one line on
stderr and exit code 2 (garage_exp.core.shell, the shell every command runs in).
"""

from __future__ import annotations

import math

from omegaconf import DictConfig

from garage_exp import config  # noqa: F401 - the experiment's Config assembled from its nodes' owners
from garage_exp.cli import callbacks
from garage_exp.core import shell
from garage_exp.core.errors import Infeasible
from garage_exp.core.overrides import quote_numeric_choices  # noqa: F401 - app.quote_numeric_choices
from garage_exp.core.state import STATE
from garage_exp.run.job import run_job

shell.register()  # importers compose the experiment's config right after (benchmarks/jobkit.py)


def failed_job(cfg: DictConfig, error: str) -> float | dict:
    """A sweep's failed job: a search trial's sweeper marks the trial failed with the error; other sweeps count
    failed runs (NaN)."""
    return {"error": error} if cfg.search.trial is not None else math.nan


def abandon_sweep(exc: BaseException) -> None:
    """The command stopped before its end: the parent run of an interrupted sweep must not stay RUNNING."""
    callbacks.abandon_sweep(STATE.sweep, exc)


# Module-level functions, not lambdas: a launcher that runs jobs elsewhere (submitit, Ray) pickles the task with
# its command, and a function pickled by value would take the process state (and its locks) along.
COMMAND = shell.Command(
    "garage_exp", "config", resume_hint="rerun the same command with resume=true to finish the sweep",
    failed_job=failed_job, on_abort=abandon_sweep)


def main(cfg: DictConfig) -> float | dict:
    """One job: its difficulty (NaN for a plan-only job), a search trial's metrics; a search trial whose sampled
    values put two actors in one another is pruned by the search (its line says why), not failed."""
    try:
        return run_job(cfg)
    except Infeasible as exc:
        if cfg.search.trial is None or not shell.refuse_job():
            raise  # a job's bad input: the shell says it in one line
        return {"error": str(exc), "infeasible": True}


def cli(argv: list[str] | None = None) -> None:
    """`python -m garage_exp [-m] overrides...`. Exit codes: 0 done; 2 bad input (one line, nothing run);
    1 a sweep finished with failed jobs (its summary lists them) or a job crashed (traceback); 130 Ctrl-C,
    143 SIGTERM (the running job's run ends KILLED; resume=true finishes the sweep)."""
    COMMAND.run(main, argv)
