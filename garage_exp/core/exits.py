"""Exit codes and input errors: every input error - ours (GarageError) and Hydra's (unknown level, wrong type,
bad override) - becomes one line on stderr and exit code 2; a bug keeps its traceback."""

from __future__ import annotations

import contextlib
import os
import sys

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE

EXIT_INPUT = 2  # bad input: one line on stderr, nothing logged
EXIT_FAILED_JOBS = 1  # a sweep ran to its end but some of its jobs failed (the summary lists them)


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler's time limit, `kill`): handled like Ctrl-C, so the job's run ends KILLED and its
    partial frame table is kept."""


class SweepStopped(BaseException):
    """A fault that every later job would meet too (a full disk, a tracking server that stays away): the job
    that met it has closed what it could, and the sweep stops here with one line and exit code 1. Not an
    Exception, so that neither the job's handler nor Hydra's launcher go on to the next job."""

    def __init__(self, what: str, hint: str):
        super().__init__(what)
        self.what, self.hint = what, hint

    def line(self, finished: int | None, jobs: int | None) -> str:
        done = f": {finished} of {jobs} jobs finished" if jobs is not None and finished is not None else ""
        return f"{self.what}{done}; {self.hint}"


def wait_seconds(variable: str, default: float = 180.0) -> float:
    """How long to wait for a server that went away: the environment variable's seconds (at least 0), else
    `default` (also when it is not a number)."""
    try:
        return max(0.0, float(os.environ.get(variable, default)))
    except ValueError:
        return default


def stopping() -> bool:
    """Ctrl-C or SIGTERM came: from now on nothing may wait on the network (tracking.retry)."""
    return STATE.stopping


def on_sigterm(signum, frame):
    _stop(Terminated(f"signal {signum} (SIGTERM)"))


def on_sigint(signum, frame):
    _stop(KeyboardInterrupt())


def _stop(interrupt: KeyboardInterrupt) -> None:
    """Raise the interrupt where the command is, or, inside signals_held, when the call held ends; a second
    signal while one is held raises at once (a user pressing Ctrl-C again means now)."""
    STATE.stop()
    if STATE.holding and STATE.held is None:
        STATE.held = interrupt
        return
    STATE.held = None
    raise interrupt


@contextlib.contextmanager
def signals_held():
    """A call to a database store in flight (the tracking store's SQL session): Ctrl-C or SIGTERM arriving now
    is raised when it returns, not inside it. Raised inside the session, the interrupt left that job's run
    RUNNING with its params half logged, or the write lock to a connection nobody would commit, so that the
    stopping command's own writes (its run ended KILLED) waited out sqlite's busy timeout: 21 s here, over the
    test's minute under CI's load (tests/faults `store:term`)."""
    STATE.holding += 1
    try:
        yield
    finally:
        STATE.holding -= 1
        if STATE.holding == 0 and STATE.held is not None:
            held, STATE.held = STATE.held, None
            raise held


def input_error(exc: BaseException) -> str | None:
    """One line for an input error (ours or Hydra's), None for anything else (a bug: traceback)."""
    import yaml
    from hydra.errors import CompactHydraException, HydraException
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(exc, GarageError):
        return str(exc)
    unknown = unknown_key_line(exc)
    if unknown is not None:
        return unknown
    if isinstance(exc, yaml.YAMLError):  # a config file that is not YAML, or asks for Python objects
        return one_line(str(exc))
    if isinstance(exc, OmegaConfBaseException) or (
            isinstance(exc, HydraException) and (isinstance(exc, CompactHydraException)
                                                 or not str(exc).startswith("Error executing job"))):
        text = str(exc)
        override = getattr(exc, "override", None)  # OverrideParseException: name the bad override
        if override and override not in text:
            text = f"override {override!r}: {text}"
        cause = exc.__cause__
        if isinstance(cause, OmegaConfBaseException) and str(cause).split("\n")[0] not in text:
            text += "\n" + str(cause)
        return one_line(text)
    return None


def unknown_key_line(exc: BaseException) -> str | None:
    """Hydra's error for a key the schema lacks, as one line naming the override (or the config file), the key
    and the nearest valid key: `case.bumper_gapp=1: case has no key 'bumper_gapp' (did you mean 'bumper_gap'?)`
    instead of Hydra's advice to add `+` (which would add a key nothing reads). None for any other error, and
    where the key's parent is an open dict (`sensor.params`, `case.actors`): there `+` is the right advice."""
    import dataclasses
    import re

    from hydra.errors import ConfigCompositionException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError

    from garage_exp.core.errors import did_you_mean

    cause = exc.__cause__ or exc.__context__  # an override's error is chained, a config file's raised in handling
    schema = getattr(cause, "object_type", None)
    if not (isinstance(exc, ConfigCompositionException) and isinstance(cause, (ConfigAttributeError, ConfigKeyError))
            and isinstance(schema, type) and dataclasses.is_dataclass(schema) and cause.key is not None
            and cause.full_key):
        return None
    key, text, names = str(cause.key), str(exc), [f.name for f in dataclasses.fields(schema)]
    if key in names:
        return None
    override = re.search(r"To append to your config use \+(\S+)", text)
    level = re.match(r"In '([^']+)'", text)
    if override:
        where = override.group(1)
    elif level:
        where = config_file(level.group(1), exc)
    else:
        return None
    owner = str(cause.full_key)[:-len(key)].rstrip(".") or (override and list_entry(where, key)) or "the config"
    return f"{where}: {owner} has no key {key!r}{did_you_mean(key, names)}"


def list_entry(override: str, key: str) -> str:
    """The entry of a list of records that an override sets which holds `key` (`search.descriptors[1]`), or "":
    OmegaConf checks each record on its own, so its error names neither the list nor the entry."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        parsed = OverridesParser.create().parse_override(override)
    except HydraException:
        return ""
    value = parsed.value()
    entries = [k for k, item in enumerate(value) if isinstance(item, dict) and key in item] if isinstance(
        value, list) else []
    return f"{parsed.key_or_group}[{entries[0]}]" if entries else ""


def config_file(name: str, exc: BaseException) -> str:
    """The YAML file of the config Hydra names ('case/mine' In its message): Hydra's composition was merging
    it (its `loaded` result names the config source, e.g. file:///.../conf) when the error came; else the name."""
    from pathlib import Path

    tb = exc.__traceback__
    while tb is not None:
        loaded = tb.tb_frame.f_locals.get("loaded") if tb.tb_frame.f_code.co_name.startswith("_compose") else None
        source = str(getattr(loaded, "path", "") or "")
        if source.startswith("file://") and (Path(source[len("file://"):]) / f"{name}.yaml").is_file():
            return str(Path(source[len("file://"):]) / f"{name}.yaml")
        tb = tb.tb_next
    return f"In '{name}'"


def one_line(text: str) -> str:
    """Hydra's and OmegaConf's messages in one line: indented details (full_key, types) folded in, lists of
    available options joined with commas."""
    parts: list[str] = []
    options: list[str] = []
    for raw in text.split("Config search path:")[0].splitlines():
        line = raw.strip()
        if not line or line.startswith(("reference_type", "object_type", "Set the environment variable")):
            continue
        if raw.startswith("\t") and parts and parts[-1].endswith(":"):  # "Available options in 'light':"
            if not line.endswith("_schema"):  # the structured-config schemas are not levels to choose
                options.append(line)
            continue
        if options:
            parts[-1] += " " + ", ".join(options)
            options = []
        if line.startswith("full_key:"):
            line = f"(key {line.split(':', 1)[1].strip()})"
        parts.append(line)
    if options:
        parts[-1] += " " + ", ".join(options)
    return " ".join(p if p.endswith((".", ":", ")")) or k == len(parts) - 1 else p + ";"
                    for k, p in enumerate(parts))


def install_error_report(prog: str = "garage_exp") -> None:
    """Hydra prints its own errors (several lines, exit 1) from `run_and_report`; ours prints input errors as
    one line starting with the command's name (`prog`) and exits 2, and leaves other errors (bugs) to Hydra's
    traceback. HYDRA_FULL_ERROR=1 bypasses both, as documented by Hydra."""
    import hydra._internal.utils as hydra_utils

    original = hydra_utils.run_and_report
    if getattr(original, "garage_exp", None) is not None:
        original.garage_exp = prog  # installed for an earlier command of this process: now this one's name
        return

    def run_and_report(func):
        try:
            return func()
        except Exception as exc:
            if os.environ.get("HYDRA_FULL_ERROR") == "1":
                raise
            line = input_error(exc)
            if line is None:
                def reraise():
                    raise exc
                return original(reraise)
            print(f"{run_and_report.garage_exp}: {line}", file=sys.stderr)
            sys.exit(EXIT_INPUT)

    run_and_report.garage_exp = prog
    hydra_utils.run_and_report = run_and_report


def wait_child(cmd: list[str], grace: float = 60.0, **popen) -> int:
    """Run a command of the project's as a child process and wait for it; its exit code. Stopped while it runs
    (Ctrl-C, SIGTERM), the child stops as its own command does on that signal (its run ends KILLED, its partial
    outputs kept), not killed with its run left RUNNING: Ctrl-C in a terminal reached the child already (one
    process group); SIGTERM is sent to the parent alone, so it is passed on. A child that does not stop within
    `grace` seconds is terminated, then killed."""
    import signal
    import subprocess

    with subprocess.Popen(cmd, **popen) as step:
        try:
            return step.wait()
        except KeyboardInterrupt as exc:
            if isinstance(exc, Terminated):
                step.send_signal(signal.SIGTERM)
            try:
                step.wait(timeout=grace)
            except subprocess.TimeoutExpired:  # a kill -INT to the parent alone, or a child that does not stop
                step.terminate()
                try:
                    step.wait(timeout=grace)
                except subprocess.TimeoutExpired:
                    step.kill()
            raise
