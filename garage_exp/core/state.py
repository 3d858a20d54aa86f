"""The process's state: what one process keeps between the jobs it runs, in one object.

The entry point (`garage_exp.cli.app.cli`) owns it: it starts each command with `begin()`, which clears what
belongs to one command (the sweep, its count of finished jobs, a stop asked for by a signal, the tracking
server's outage) and keeps what is expensive to rebuild (the warm renderer with its compiled shaders, the
detector's child process, the classified plans). Modules read and write its fields instead of keeping
globals of their own, so a test or a second command in one process starts from a known state.
"""

from __future__ import annotations

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

    def begin(self) -> ProcessState:
        """A new command in this process: forget the last one's sweep, counts and outage, keep the warm parts."""
        self.sweep = None
        self.finished_jobs = 0
        self.stopping = False
        self.tracking_down_since = None
        self.tracking_given_up = False
        return self


STATE = ProcessState()
