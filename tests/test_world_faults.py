"""Faults in the world around a sweep (issue 14), each injected for real: two processes racing on a fresh
sqlite store, a store left broken, a detector process killed with SIGKILL, a full disk, a tracking server
that goes away. Each test checks what is kept, the one line the user is told (no traceback) and the exit
code. Plan-only jobs (dry_run=true) keep the sweeps fast."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import PYTHON, child_env, run_app

from garage_exp import tracking
from garage_exp.detect import worker
from garage_exp.errors import GarageError

DRY = ["dry_run=true", "plan=tiny"]


def one_line_error(stderr: str) -> str:
    """The last line of stderr, after checking that no traceback came before it."""
    assert "Traceback" not in stderr, stderr[-3000:]
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert lines, "nothing on stderr"
    return lines[-1]


# --- the detector's process dies ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def spec():
    from test_detect import default_models

    return {"models": default_models()[:1], "classes": ("car", "truck", "bus"), "conf": 0.05, "imgsz": 320,
            "device": "cpu"}


@pytest.fixture(scope="module")
def frames():
    from test_detect import bus_image

    _, rgb = bus_image()
    return [rgb, np.ascontiguousarray(rgb[::2, ::2]), np.ascontiguousarray(rgb[:, ::-1])]


def same(a, b):
    assert [d.model for d in a] == [d.model for d in b]
    for x, y in zip(a, b):
        np.testing.assert_allclose(x.confs, y.confs, atol=1e-6)
        np.testing.assert_allclose(x.boxes, y.boxes, atol=1e-3)


@pytest.mark.detect
def test_a_killed_detector_process_is_replaced_and_its_frames_sent_again(spec, frames, caplog):
    from garage_exp.detect.detector import Detector

    expected = [Detector(**spec, threads=1).detect(f) for f in frames]
    child = worker.DetectorProcess(threads=1)
    try:
        child.load(spec)
        child.names  # noqa: B018 - loaded
        first = child.pid
        child.submit(frames[0])
        child.submit(frames[1])
        os.kill(first, signal.SIGKILL)  # two frames in flight, answered or not
        got = [child.result()]
        child.submit(frames[2])
        got += [child.result(), child.result()]
        assert child.pid != first and child.alive() and child.restarts == 1
        for a, b in zip(got, expected):
            same(a, b)
        said = [r.getMessage() for r in caplog.records if "detector process died" in r.getMessage()]
        assert len(said) == 1 and "exit code -9" in said[0] and "restart 1 of 2" in said[0]
        child.load(spec)  # the next job has its own two restarts
        assert child.restarts == 0
    finally:
        child.close()


@pytest.mark.detect
def test_only_repeated_deaths_fail_the_job(spec, frames, monkeypatch):
    """Every replacement dies at once: two restarts, then the job's error names the deaths."""
    child = worker.DetectorProcess(threads=1)
    real_start = worker.DetectorProcess._start

    def start_and_die(self):
        real_start(self)
        self._proc.kill()

    try:
        child.load(spec)
        child.names  # noqa: B018
        monkeypatch.setattr(worker.DetectorProcess, "_start", start_and_die)
        child.submit(frames[0])
        os.kill(child.pid, signal.SIGKILL)
        with pytest.raises(RuntimeError, match=r"the detector process died \(exit code -9, 3 times in this job\)"):
            child.result()
        assert not child.alive()
    finally:
        child.close()
