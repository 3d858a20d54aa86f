"""The one shell around every command: the Hydra ones (`python -m garage_exp`, `.gym`, `.train`, `.loop`,
`.verify`: `Command.run`) and the argparse ones (`.plan`, `.report`, `.report.search_analysis`, `.exports`,
`.assets`, `.scenario.import`, `.tracking.store`, `.tracking.ui`: `Command.run_args`).

Each command is a thin task - `task(cfg) -> result` for Hydra, `body(args) -> exit code` for argparse - and a
`Command` naming it (and, for Hydra, its config and its schemas); the shell does the rest the same way for all of
them (as lightning-hydra-template's `task_wrapper` does):
- composition (Hydra): the `${garage_root:}` resolver and the schemas registered, the config composed by Hydra
  from `conf/<config>.yaml`, numeric group choices quoted (`case=1`);
- the process state: `STATE.begin()` before the command, `STATE.end()` after it (`command_scope`);
- the user's registrations: the modules named in $GARAGE_EXP_PLUGINS imported before the command checks anything
  (a search's sweeper, a loop's steps, an importer's arguments), and again in each job (a job a launcher runs in
  another process);
- exit codes: 0 done; 2 bad input (a `GarageError`, Hydra's own input errors or argparse's usage errors: one line
  on stderr starting with the command's name, `garage_exp.train: ...`, nothing written); 1 a sweep finished with
  failed jobs, a sweep stopped by a fault every later job would meet too, or a crash (traceback); 130 Ctrl-C and
  143 SIGTERM with one line, after the running job's MLflow run ended KILLED (each task's run is a
  `tracking.runs.tracked_run`, which ends it KILLED on KeyboardInterrupt, which both signals raise);
- output clean-up: Hydra makes the run dir before the task starts; a task refused for bad input leaves nothing
  (`remove_untouched`, `refuse_job`).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading
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

    from garage_exp.core import hydra_mode, schema

    hydra_mode.install()  # the config composed once per command, not once more for hydra.mode
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


def multirun() -> bool:
    """Whether the running Hydra job is one job of a multirun (`-m`)."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.get().mode == RunMode.MULTIRUN


def refuse_job() -> bool:
    """The running Hydra job is refused (bad input, an infeasible trial, no room left): its run dir goes while it
    holds nothing but Hydra's own files (`remove_untouched`). Returns whether the job is one of a multirun: there
    the sweep decides what comes next (it goes on, prunes the trial, or stops), a single run exits."""
    from hydra.core.hydra_config import HydraConfig

    remove_untouched(Path(HydraConfig.get().runtime.output_dir))
    return multirun()


@contextlib.contextmanager
def command_scope():
    """What every command runs in: the process state begun for it (this command's sweep, counts and outages; the
    warm renderer and detector stay) and ended after it; Ctrl-C and SIGTERM raising KeyboardInterrupt and
    Terminated where the command is (signal handlers exist only in the main thread: a command run from another
    thread keeps the process's); logging quiet about records it cannot write. Yields STATE."""
    from garage_exp.core.state import STATE

    state = STATE.begin()
    # On a full disk every log record that cannot be written would print a traceback of its own (Python's
    # logging default); the job reports the full disk once instead. Only for the command: put back after it.
    raise_exceptions, logging.raiseExceptions = logging.raiseExceptions, False
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {sig: signal.signal(sig, handler) for sig, handler in
                    ((signal.SIGTERM, on_sigterm), (signal.SIGINT, on_sigint))}
    try:
        yield state
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        logging.raiseExceptions = raise_exceptions
        STATE.end()


@dataclass(frozen=True)
class Command:
    """A command: `prog` names it at the start of its one-line errors (`garage_exp.train`, `garage_exp.plan`). A
    Hydra command's config is `conf/<config_name>.yaml`, typed by the schemas its `schemas` functions store; an
    argparse command has none."""

    prog: str
    config_name: str | None = None
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
            sweeping = self.failed_job is not None and multirun()
            try:
                import_plugins()  # a job a launcher runs in another process (Ray, submitit) imports them there too
                return task(cfg)
            except GarageError as exc:
                refuse_job()
                self.say(exc)
                if not sweeping:
                    sys.exit(EXIT_INPUT)
                error = str(exc)
            except JobFault as exc:  # the job's run ended FAILED, its partial outputs kept: one line, no traceback
                self.say(exc)
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
        """Run the Hydra command on `argv` (default: the process's), with its exit code as the docstring above
        says; returns on success (exit 0)."""
        import hydra

        sys.argv[1:] = quote_numeric_choices(sys.argv[1:] if argv is None else list(argv))
        register(*self.schemas)
        install_error_report(self.prog)
        main = hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name=self.config_name)(
            self.task(task))
        with command_scope() as state:
            try:
                # The user's registrations before anything is checked: a search's sweeper checks its objective and
                # its detector's entries before any job starts.
                import_plugins()
            except GarageError as exc:
                self.say(exc)
                sys.exit(EXIT_INPUT)
            try:
                main()
            except BaseException as exc:
                if self.on_abort is not None:
                    self.on_abort(exc)
                code = self.exit_code(exc, state)
                if code is not None:
                    sys.exit(code)
                raise
            failed = state.sweep is not None and state.sweep.failures
        if failed:
            sys.exit(EXIT_FAILED_JOBS)

    def run_args(self, parser: argparse.ArgumentParser, body: Callable[[argparse.Namespace], int | None],
                 argv: Sequence[str] | None = None) -> int:
        """Run the argparse command: `argv` (default: the process's) parsed by `parser`, then `body(args)`; returns
        the exit code (the caller's `sys.exit` ends the process with it): body's own (None: 0), 2 bad input (a
        GarageError or a usage error: one line, `prog: ...`), 130 Ctrl-C and 143 SIGTERM (one line); a crash
        propagates with its traceback (exit 1)."""
        args = self.parse(parser, argv)
        if isinstance(args, int):
            return args
        with command_scope() as state:
            try:
                import_plugins()  # the user's registrations before the body checks its arguments
                return int(body(args) or 0)
            except GarageError as exc:
                self.say(exc)
                return EXIT_INPUT
            except BaseException as exc:
                code = self.exit_code(exc, state)
                if code is None:
                    raise
                return code

    def parse(self, parser: argparse.ArgumentParser, argv: Sequence[str] | None) -> argparse.Namespace | int:
        """The parsed arguments, or the exit code when parsing ended the command: 0 after --help, 2 after a usage
        error, said in one line (argparse's own usage block and `error:` line folded into it)."""
        import io

        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                return parser.parse_args(argv)
        except SystemExit as exc:
            if not exc.code:
                return 0
            last = ([ln for ln in err.getvalue().splitlines() if ln.strip()] or ["bad arguments"])[-1]
            message = last.split(": error: ", 1)[-1]
            self.say(f"{message} (see {parser.prog} --help)")
            return EXIT_INPUT

    def say(self, line: Any) -> None:
        """One line on stderr, the command's name first: how every command says an error or why it stopped."""
        print(f"{self.prog}: {line}", file=sys.stderr)

    def exit_code(self, exc: BaseException, state) -> int | None:
        """The exit code for an exception that ends the command, its one line said; None for a bug (its traceback
        follows) and for an exit already decided."""
        if isinstance(exc, SweepStopped):  # a full disk, a tracking server away: the job said what it kept
            sweep = state.sweep
            jobs = sweep.jobs if sweep is not None and sweep.in_process else None
            self.say(exc.line(state.finished_jobs, jobs))
            return EXIT_FAILED_JOBS
        if isinstance(exc, KeyboardInterrupt):  # the job's run already ended KILLED, its partial outputs kept
            terminated = isinstance(exc, Terminated)
            hint = f"; {self.resume_hint}" if self.resume_hint else ""
            self.say(f"{'terminated (SIGTERM)' if terminated else 'interrupted'}{hint}")
            return 128 + (signal.SIGTERM if terminated else signal.SIGINT)
        if isinstance(exc, ValueError) and str(exc).startswith("Only one of --run"):  # Hydra's own flag check
            self.say(f"{exc} (--cfg prints a single job's config: drop -m)")
            return EXIT_INPUT
        return None
