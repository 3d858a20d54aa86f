"""The process's state: what one process keeps between the jobs it runs, in one object.

The command shell (`garage_exp.core.shell`, around every Hydra command) owns it: it starts each command with
`begin()` and closes it with `end()`, which clear what belongs to one command (the sweep, its count of finished
jobs, a stop asked for by a signal and what the stop changed, the tracking server's outage) and keep what is
expensive to rebuild (the warm renderer with its compiled shaders, the detector's child process, the classified
plans). Modules read and write its fields instead of keeping
globals of their own, so a test or a second command in one process starts from a known state.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any


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

    stopped_env: dict = field(default_factory=dict)  # what stop() changed in os.environ: name -> earlier value

    # A request already on its way to a server that hangs must not hold a stopping command's exit either.
    STOP_ENV = {"MLFLOW_HTTP_REQUEST_TIMEOUT": "3", "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0"}

    def stop(self) -> None:
        """Ctrl-C or SIGTERM came: from now on nothing may wait on the network (tracking.retry)."""
        self.stopping = True
        for name, value in self.STOP_ENV.items():
            self.stopped_env.setdefault(name, os.environ.get(name))
            os.environ[name] = value

    def begin(self) -> ProcessState:
        """A new command in this process: forget the last one's sweep, counts and outage, keep the warm parts."""
        self._forget_command()
        return self

    def end(self) -> None:
        """The command is over: the process (a test session, a benchmark running commands in turn) keeps no part
        of it, nor the network time-outs its stop set."""
        self._forget_command()

    def _forget_command(self) -> None:
        self.sweep = None
        self.finished_jobs = 0
        self.stopping = False
        self.tracking_down_since = None
        self.tracking_given_up = False
        for name, value in self.stopped_env.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        self.stopped_env.clear()


STATE = ProcessState()
