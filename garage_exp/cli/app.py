"""The Hydra application: the entry point (`main`) and the command line (`cli`).

Bad input never costs a run: the job (garage_exp.run.job) checks its inputs first (garage_exp.run.preflight), a sweep
checks all its jobs before the first starts (garage_exp.cli.callbacks), and every input error becomes one line on
stderr and exit code 2 (garage_exp.core.exits).
"""

from __future__ import annotations

import logging
import math
import signal
import sys
import traceback

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from garage_exp.core.overrides import quote_numeric_choices  # noqa: F401 - app.quote_numeric_choices
from garage_exp.cli import callbacks
from garage_exp.core import schema
from garage_exp.core.exits import (EXIT_FAILED_JOBS, EXIT_INPUT, SweepStopped, Terminated, install_error_report,
                                   on_sigint, on_sigterm)
from garage_exp.core.errors import GarageError, Infeasible
from garage_exp.core.paths import PROJECT_ROOT
from garage_exp.core.state import STATE
from garage_exp.run.job import run_job

log = logging.getLogger("garage_exp")

if not OmegaConf.has_resolver("garage_root"):
    OmegaConf.register_new_resolver("garage_root", lambda: str(PROJECT_ROOT))
schema.register()


@hydra.main(version_base="1.3", config_path=str(PROJECT_ROOT / "conf"), config_name="config")
def main(cfg: DictConfig) -> float | dict:
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    try:
        return run_job(cfg)
    except GarageError as exc:
        if multirun and isinstance(exc, Infeasible) and cfg.search.trial is not None:
            return {"error": str(exc), "infeasible": True}  # the search prunes the trial (its line says why)
        print(f"garage_exp: {exc}", file=sys.stderr)
        if not multirun:
            sys.exit(EXIT_INPUT)
        error = str(exc)
    except Exception as exc:
        if not multirun:
            raise
        # The run is already marked FAILED with its error; the sweep goes on.
        log.error("job failed:\n%s", traceback.format_exc())
        error = f"{type(exc).__name__}: {exc}".strip()
    # A search trial's sweeper marks the trial failed with the error; other sweeps count failed runs.
    return {"error": error} if cfg.search.trial is not None else math.nan


def cli(argv: list[str] | None = None) -> None:
    """`python -m garage_exp [-m] overrides...`. Exit codes: 0 done; 2 bad input (one line, nothing run);
    1 a sweep finished with failed jobs (its summary lists them) or a job crashed (traceback); 130 Ctrl-C,
    143 SIGTERM (the running job's run ends KILLED; resume=true finishes the sweep)."""
    sys.argv[1:] = quote_numeric_choices(sys.argv[1:] if argv is None else list(argv))
    state = STATE.begin()  # this command's sweep, counts and outages; the warm renderer and detector stay
    install_error_report()
    # On a full disk every log record that cannot be written would print a traceback of its own (Python's
    # logging default); the job reports the full disk once instead.
    logging.raiseExceptions = False
    previous = signal.signal(signal.SIGTERM, on_sigterm)
    previous_int = signal.signal(signal.SIGINT, on_sigint)
    try:
        main()
    except BaseException as exc:
        callbacks.abandon_sweep(state.sweep, exc)  # the parent run of an interrupted sweep must not stay RUNNING
        if isinstance(exc, SweepStopped):  # a full disk, a tracking server away: the job said what it kept
            sweep = state.sweep
            jobs = sweep.jobs if sweep is not None and sweep.in_process else None
            print(f"garage_exp: {exc.line(state.finished_jobs, jobs)}", file=sys.stderr)
            sys.exit(EXIT_FAILED_JOBS)
        if isinstance(exc, KeyboardInterrupt):  # the job's run already ended KILLED, its partial table kept
            terminated = isinstance(exc, Terminated)
            print(f"garage_exp: {'terminated (SIGTERM)' if terminated else 'interrupted'}; rerun the same "
                  "command with resume=true to finish the sweep", file=sys.stderr)
            sys.exit(128 + (signal.SIGTERM if terminated else signal.SIGINT))
        if isinstance(exc, ValueError) and str(exc).startswith("Only one of --run"):  # Hydra's own flag check
            print(f"garage_exp: {exc} (--cfg prints a single job's config: drop -m)", file=sys.stderr)
            sys.exit(EXIT_INPUT)
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)
    if state.sweep is not None and state.sweep.failures:
        sys.exit(EXIT_FAILED_JOBS)
