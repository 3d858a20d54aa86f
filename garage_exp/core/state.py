"""The process's state: what one process keeps between the jobs it runs, in one object.

Every memo, cache and warm resource of the package lives here, with its *scope*, the span it is good for:

- `process`: expensive to rebuild and still right for any later command: the warm renderer (its shaders), the
  detector's child process (its models), loaded models and asset libraries, the render device, memos of pure
  functions (a texture by seed, a plan's classification by content).
- `command`: belongs to one command: the sweep, its count of finished jobs, a stop asked for by a signal, the
  tracking server's outage, the checked search spaces, the stores opened.
- `job`: belongs to one job of a sweep.

The command shell (`garage_exp.core.shell`, around every Hydra command) starts each command with `begin()` and
closes it with `end()` (both clear the command and job scopes, and undo what a stop changed in the environment), a
job starts with `begin_job()` (clears the job scope), and a test that wants a fresh process calls
`clear("process")`. Modules read and write STATE's fields, or keep a cache that STATE made (`STATE.cache(name, scope)`, a
dict) or a memo it registered (`@STATE.memo(scope)`, an `lru_cache`), instead of module globals of their own:
`tests/test_state.py` fails on a module-level cache that STATE does not know.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

SCOPES = ("process", "command", "job")  # widest first: clearing one clears those narrower too


@dataclass
class ProcessState:
    sweep: Any = None  # the running sweep's callback (cli.callbacks.MlflowSweepCallback), None for one job
    finished_jobs: int = 0  # jobs of this process that finished (or had before): what a stopped sweep reports
    stopping: bool = False  # SIGINT/SIGTERM asked the process to stop: no more waiting for a tracking server
    tracking_down_since: float | None = None  # when the tracking server stopped answering (None: it answers)
    tracking_given_up: bool = False  # the wait for it ran out: later calls fail at once instead of waiting again
    renderer: Any = None  # the warm renderer (shaders compile once per process)
    detector: Any = None  # the detector's child process (models load once per process)
    plans: dict = field(default_factory=dict)  # plan path -> ((mtime, size), classified plan): sweeps check many jobs
    maps: dict = field(default_factory=dict)  # a plan's digest -> its map's PNG bytes: a sweep's jobs share one plan
    # name -> (scope, clear): every registered cache and memo, and how to empty it
    registered: dict[str, tuple[str, Callable[[], None]]] = field(default_factory=dict)
    # What this process changed in os.environ, by scope: name -> the value before (None: it was unset). Clearing a
    # scope puts those back, so a command leaves the environment as it found it (setenv below).
    saved_env: dict[str, dict[str, str | None]] = field(default_factory=lambda: {scope: {} for scope in SCOPES})
    in_command: bool = False  # between begin() and end(): a command runs
    pool_level: int | None = None  # the store pool logger's level before a stop quieted it (None: not quieted)
    holding: int = 0  # store calls in flight that a signal must not interrupt (core.exits.signals_held)
    held: BaseException | None = None  # the Ctrl-C or SIGTERM that came during one, raised when it ends

    # A request already on its way to a server that hangs must not hold a stopping command's exit either.
    STOP_ENV = {"MLFLOW_HTTP_REQUEST_TIMEOUT": "3", "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0"}

    # The interrupt raised inside an SQLite fetch (MLflow's or Optuna's store): SQLAlchemy then closes the connection
    # and logs, at ERROR with a traceback, that it could not close the cursor of that closed connection. Noise of the
    # stop itself, which buried the one line a stopped command says; quiet from the stop to the command's end.
    QUIET_ON_STOP = "sqlalchemy.pool"

    def stop(self) -> None:
        """Ctrl-C or SIGTERM came: from now on nothing may wait on the network (tracking.retry), and a store's
        connection pool does not log the teardown the interrupt caused."""
        import logging

        self.stopping = True
        for name, value in self.STOP_ENV.items():
            self.setenv(name, value, "command")
        pool = logging.getLogger(self.QUIET_ON_STOP)
        if self.pool_level is None:
            self.pool_level = pool.level
        pool.setLevel(logging.CRITICAL + 1)

    def setenv(self, name: str, value: str, scope: str, *, default: bool = False) -> str:
        """Set $name for `scope` (one of SCOPES): clearing that scope puts back the value it had before (or unsets
        it). With `default`, a value already there is kept (os.environ.setdefault). The package writes the process
        environment only through here (tests/test_state.py), so no command leaks its tracking store or time-outs
        into the next one run in the same process (a test session, a benchmark, the loop's steps)."""
        if scope not in SCOPES:
            raise ValueError(f"scope must be one of {SCOPES}, got {scope!r}")
        if default and name in os.environ:
            return os.environ[name]
        # Outside a command (a library call: a notebook's or a test's tracking.client), a command's or job's
        # setting is simply set, as before: only a running command has an end that puts it back, and recording it
        # would make the next command's begin undo what its caller set in between.
        if (scope == "process" or self.in_command) and not any(name in saved for saved in self.saved_env.values()):
            self.saved_env[scope][name] = os.environ.get(name)
        os.environ[name] = value
        return value

    def popenv(self, name: str, scope: str) -> None:
        """Unset $name for `scope`, as setenv sets it."""
        if name in os.environ:
            if (scope == "process" or self.in_command) and not any(name in saved for saved in self.saved_env.values()):
                self.saved_env[scope][name] = os.environ[name]
            del os.environ[name]

    def _restore_env(self, scopes) -> None:
        for scope in scopes:
            for name, value in self.saved_env[scope].items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value
            self.saved_env[scope].clear()

    def register(self, name: str, scope: str, clear: Callable[[], None]) -> None:
        """Record a cache's `clear` under `scope` (one of SCOPES); the same name again replaces it (a reload)."""
        if scope not in SCOPES:
            raise ValueError(f"scope must be one of {SCOPES}, got {scope!r}")
        self.registered[name] = (scope, clear)

    def cache(self, name: str, scope: str) -> dict:
        """A dict for a module's cache, emptied when `scope` is cleared."""
        store: dict = {}
        self.register(name, scope, store.clear)
        return store

    def memo(self, scope: str, maxsize: int | None = 128) -> Callable:
        """`functools.lru_cache(maxsize)` registered under `scope`: for pure functions of small immutable inputs."""
        def wrap(fn: Callable) -> Callable:
            cached = functools.lru_cache(maxsize=maxsize)(fn)
            self.register(f"{fn.__module__}.{fn.__qualname__}", scope, cached.cache_clear)
            return cached
        return wrap

    def clear(self, scope: str) -> None:
        """Empty every cache of `scope` and of the scopes narrower than it (and the fields of those scopes)."""
        narrower = SCOPES[SCOPES.index(scope):]
        for kind, clear in list(self.registered.values()):
            if kind in narrower:
                clear()
        if "command" in narrower:
            self.sweep = None
            self.finished_jobs = 0
            self.stopping = False
            self.holding, self.held = 0, None
            if self.pool_level is not None:
                import logging

                logging.getLogger(self.QUIET_ON_STOP).setLevel(self.pool_level)
                self.pool_level = None
            self.tracking_down_since = None
            self.tracking_given_up = False
        self._restore_env(narrower)
        if scope == "process":
            self.plans.clear()
            self.maps.clear()
            # The warm renderer and the detector's child process are process resources: a fresh process has
            # neither, and the child's models and memory go with it now, not at interpreter exit.
            detector, self.detector, self.renderer = self.detector, None, None
            if detector is not None and hasattr(detector, "close"):
                detector.close()

    def begin(self) -> ProcessState:
        """A new command in this process: forget the last one's sweep, counts, outage and command caches, keep
        the warm parts. The environment is taken as the caller leaves it: what was set since the last command
        ended (by its caller, or by a library call) is neither put back nor undone here; only what this command
        sets is put back at its end."""
        for scope in ("command", "job"):
            self.saved_env[scope].clear()
        self.clear("command")
        self.in_command = True
        return self

    def end(self) -> None:
        """The command is over: the process (a test session, a benchmark running commands in turn) keeps no part
        of it, nor the environment it set (its tracking store, the network time-outs its stop set)."""
        self.clear("command")
        self.in_command = False

    def begin_job(self) -> ProcessState:
        """A new job of the command: forget the last job's caches."""
        self.clear("job")
        return self


STATE = ProcessState()
