"""The one shell around every Hydra command (`python -m garage_exp`, `.gym`, `.train`, `.loop`, `.verify`).

Each command is a thin task, `task(cfg) -> result`, and a `Command` naming it, its config and its schemas; the
shell does the rest the same way for all of them (as lightning-hydra-template's `task_wrapper` does):
- composition: the `${garage_root:}` resolver and the schemas registered, the config composed by Hydra from
  `conf/<config>.yaml`, numeric group choices quoted (`case=1`);
- the process state: `STATE.begin()` before the command, `STATE.end()` after it;
- exit codes: 0 done; 2 bad input (a `GarageError` or Hydra's own input errors: one line on stderr starting with
  the command's name, nothing written); 1 a sweep finished with failed jobs, a sweep stopped by a fault every
  later job would meet too, or a crash (traceback); 130 Ctrl-C and 143 SIGTERM, after the running job's MLflow
  run ended KILLED (each task ends its run on KeyboardInterrupt, which both signals raise);
- output clean-up: Hydra makes the run dir before the task starts; a task refused for bad input leaves nothing
  (`remove_untouched`).
"""

from __future__ import annotations

import logging
import signal
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from garage_exp.core.errors import GarageError, JobFault
from garage_exp.core.exits import (EXIT_FAILED_JOBS, EXIT_INPUT, SweepStopped, Terminated, install_error_report,
                                   on_sigint, on_sigterm)
from garage_exp.core.overrides import quote_numeric_choices
from garage_exp.core.paths import OUTPUTS_DIR, PROJECT_ROOT
from garage_exp.core.plugins import import_plugins

log = logging.getLogger("garage_exp")
CONF_DIR = PROJECT_ROOT / "conf"


def register(*schemas: Callable[[], None]) -> None:
    """The `${garage_root:}` resolver and the config schemas: the experiment's (every config that composes
    `config` needs it) and each command's own (`schemas`: their `register` functions). Idempotent."""
    from omegaconf import OmegaConf

    from garage_exp.core import schema

    if not OmegaConf.has_resolver("garage_root"):
        OmegaConf.register_new_resolver("garage_root", lambda: str(PROJECT_ROOT))
    schema.register()
    for store in schemas:
        store()


def compose(config_name: str = "config", overrides: Sequence[str] = (), *, schemas: Sequence[Callable] = (),
            hydra: bool = False):
    """The config as the command that reads `conf/<config_name>.yaml` composes it from OVERRIDES (numeric group
    choices quoted), outside a command; hydra=True keeps the `hydra` node (sweeper params, launcher). A caller's
    own Hydra (a benchmark after a search in its process) is set aside for the call, then restored."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    register(*schemas)
    global_hydra = GlobalHydra.instance()
    saved = global_hydra.hydra if global_hydra.is_initialized() else None
    global_hydra.clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            return hydra_compose(config_name=config_name, overrides=quote_numeric_choices(list(overrides)),
                                 return_hydra_config=hydra)
    finally:
        if saved is not None:
            GlobalHydra.instance().initialize(saved)


def remove_untouched(out: Path) -> None:
    """Hydra makes a run's dir (config copies, log) and the folders above it before the task starts; a task
    refused for bad input leaves nothing behind. The dir goes only while it holds nothing but Hydra's own files;
    then each folder above it that is left empty (the date levels of `${now:}` dirs, a loop's own `dir`), up to
    the project's outputs folder or the working directory, which stay."""
    import os
    import shutil

    keep = {OUTPUTS_DIR.resolve(), *Path(os.getcwd()).resolve().parents, Path(os.getcwd()).resolve()}
    try:
        if not out.is_dir() or any(p.name != ".hydra" and p.suffix != ".log" for p in out.iterdir()):
            return
        shutil.rmtree(out)
        parent = out.resolve().parent
        while parent not in keep and not any(parent.iterdir()):
            parent.rmdir()
            parent = parent.parent
    except OSError:  # another process wrote there meanwhile, or a read-only tree: leave it
        pass


@dataclass(frozen=True)
class Command:
    """A Hydra command: `prog` names it at the start of its one-line errors (`garage_exp.train`); its config is
    `conf/<config_name>.yaml`, typed by the schemas its `schemas` functions store."""

    prog: str
    config_name: str
    schemas: tuple[Callable[[], None], ...] = ()
    # After Ctrl-C or SIGTERM: how to go on (a sweep resumes with resume=true, the loop by its own rerun).
    resume_hint: str = ""
    # A sweep's job that failed (bad input, a crash) does not stop the sweep: what the job returns instead,
    # from its config and the error's line. None: the command stops at the first failed job, as a single run does.
    failed_job: Callable[[Any, str], Any] | None = None
    # The command stopped before its end (a signal, a crash, a stopped sweep): close what it opened for the whole
    # command (the sweep's parent run), given the exception.
    on_abort: Callable[[BaseException], None] | None = None

    def task(self, task: Callable[[Any], Any]) -> Callable[[Any], Any]:
        """`task` as Hydra runs it for each job: bad input is cleaned up after and becomes one line and exit 2;
        in a sweep that goes on past failed jobs (`failed_job`), the job's error is its result instead."""
        def job(cfg):
            from hydra.core.hydra_config import HydraConfig
            from hydra.types import RunMode

            hc = HydraConfig.get()
            sweeping = self.failed_job is not None and hc.mode == RunMode.MULTIRUN
            try:
                import_plugins()  # the user's registrations ($GARAGE_EXP_PLUGINS) before the config is checked
                return task(cfg)
            except GarageError as exc:
                remove_untouched(Path(hc.runtime.output_dir))
                print(f"{self.prog}: {exc}", file=sys.stderr)
                if not sweeping:
                    sys.exit(EXIT_INPUT)
                error = str(exc)
            except JobFault as exc:  # the job's run ended FAILED, its partial outputs kept: one line, no traceback
                print(f"{self.prog}: {exc}", file=sys.stderr)
                if not sweeping:
                    sys.exit(EXIT_FAILED_JOBS)
                error = f"{type(exc).__name__}: {exc}"
            except Exception as exc:
                if not sweeping:
                    raise
                # The job's run is already marked FAILED with its error; the sweep goes on.
                log.error("job failed:\n%s", traceback.format_exc())
                error = f"{type(exc).__name__}: {exc}".strip()
            return self.failed_job(cfg, error)

        job.__name__ = job.__qualname__ = getattr(task, "__name__", "task")
        job.__module__ = getattr(task, "__module__", __name__)
        return job

    def run(self, task: Callable[[Any], Any], argv: Sequence[str] | None = None) -> None:
        """Run the command on `argv` (default: the process's), with its exit code as the docstring above says;
        returns on success (exit 0)."""
        import hydra

        from garage_exp.core.state import STATE

        sys.argv[1:] = quote_numeric_choices(sys.argv[1:] if argv is None else list(argv))
        register(*self.schemas)
        state = STATE.begin()  # this command's sweep, counts and outages; the warm renderer and detector stay
        install_error_report(self.prog)
        # On a full disk every log record that cannot be written would print a traceback of its own (Python's
        # logging default); the job reports the full disk once instead. Only for the command: put back after it.
        raise_exceptions, logging.raiseExceptions = logging.raiseExceptions, False
        main = hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name=self.config_name)(
            self.task(task))
        previous = {sig: signal.signal(sig, handler) for sig, handler in
                    ((signal.SIGTERM, on_sigterm), (signal.SIGINT, on_sigint))}
        try:
            main()
            failed = state.sweep is not None and state.sweep.failures
        except BaseException as exc:
            if self.on_abort is not None:
                self.on_abort(exc)
            self.exit_for(exc, state)
            raise
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            logging.raiseExceptions = raise_exceptions
            STATE.end()
        if failed:
            sys.exit(EXIT_FAILED_JOBS)

    def exit_for(self, exc: BaseException, state) -> None:
        """Exit with the code and the one line for an exception that ends the command; returns for a bug (its
        traceback follows) and for an exit already decided."""
        if isinstance(exc, SweepStopped):  # a full disk, a tracking server away: the job said what it kept
            sweep = state.sweep
            jobs = sweep.jobs if sweep is not None and sweep.in_process else None
            print(f"{self.prog}: {exc.line(state.finished_jobs, jobs)}", file=sys.stderr)
            sys.exit(EXIT_FAILED_JOBS)
        if isinstance(exc, KeyboardInterrupt):  # the job's run already ended KILLED, its partial outputs kept
            terminated = isinstance(exc, Terminated)
            hint = f"; {self.resume_hint}" if self.resume_hint else ""
            print(f"{self.prog}: {'terminated (SIGTERM)' if terminated else 'interrupted'}{hint}", file=sys.stderr)
            sys.exit(128 + (signal.SIGTERM if terminated else signal.SIGINT))
        if isinstance(exc, ValueError) and str(exc).startswith("Only one of --run"):  # Hydra's own flag check
            print(f"{self.prog}: {exc} (--cfg prints a single job's config: drop -m)", file=sys.stderr)
            sys.exit(EXIT_INPUT)
