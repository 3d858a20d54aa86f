"""Detection beside rendering: the detectors run in a child process while the job renders the next frame.

Why a process and not a thread: SAPIEN's `take_picture` holds the GIL for the whole render (a Python thread
spinning beside it ran at 5% of its idle rate), so a detection thread stalls whenever it needs Python between
OpenVINO calls; overlapped frames measured no faster than serial ones. A child has its own GIL.

One child per process (`open_detector`), kept across jobs like the renderer, so a sweep worker loads the
models once. Frames go down a pipe (0.9 MB at 640x480, about a millisecond); detections come back pickled. The
child answers requests in order, so results are the frames' in submission order and every result is computed
from its frame alone: overlap cannot change a confidence.

`GARAGE_EXP_DETECT_PROCESS=0` runs the same interface in-process and serially: submit() only queues, result()
detects.
"""

from __future__ import annotations

import atexit
import logging
import os
import signal
import socket
import subprocess
import sys
from collections import deque
from multiprocessing.connection import Connection
from dataclasses import replace

import numpy as np

from garage_exp.core.errors import GarageError, JobFault
from garage_exp.core.logfile import FILE_LOG
from garage_exp.core.plugins import import_plugins
from garage_exp.core.state import STATE
from garage_exp.perception.detect.base import Detections, as_batch, message_of, per_frame
from garage_exp.perception.detect.detector import Detector
from garage_exp.scene.lenses import Lens

log = logging.getLogger("garage_exp")


def cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 2


# OpenVINO threads in the child: half the cores, the renderer beside it keeps the rest busy. On 2 cores one
# thread detects at 0.104 CPU s a frame against 0.125 with two (docs/performance.md), so the pair wastes
# less. GARAGE_EXP_OV_THREADS overrides (0: OpenVINO's default, all cores).
DEFAULT_THREADS = max(1, cores() // 2)


class InlineDetector:
    """The serial fallback: detection on the calling thread when its result is asked for."""

    def __init__(self, detector: Detector, probe: Lens | None = None, threads: int = 0):
        self._threads = threads
        self._detector: Detector | None = None
        self._queue: deque[tuple[np.ndarray, Lens | None]] = deque()
        self.load(detector, probe)

    def load(self, detector: Detector, probe: Lens | None = None) -> None:
        """Use `detector` from now on (checked on the probe), as `DetectorProcess.load`; the same one is kept."""
        self.drain()
        if detector != self._detector:
            self._detector = replace(detector, threads=self._threads)
            self._detector.check(probe)
            self.names = self._detector.names

    @property
    def loaded(self) -> Detector | None:
        return self._detector

    def submit(self, rgb: np.ndarray, intrinsics: Lens | None = None) -> None:
        self._queue.append((rgb, intrinsics))

    def result(self) -> list[Detections]:
        rgb, intrinsics = self._queue.popleft()
        return self._detector.detect([rgb], [intrinsics])[0]

    def drain(self) -> None:
        self._queue.clear()

    abandon = drain


class DetectorProcess:
    """A child process holding a `Detector`: `submit(rgb, intrinsics)` sends a frame, `result()` returns the oldest
    one's detections (one `Detections` per model). Reconfigure with `load(detector, probe)`: the child checks the
    detector (every entry loaded and run on a probe frame of the camera `probe`) and keeps every model it loaded.

    A child that dies (the OOM killer, `kill -9`, a crash in a native library) is replaced: a new child loads
    the same detectors and gets the frames the dead one had not answered, in order, so the job's results are
    the same as without the fault. At most RESTARTS times per job (per `load`); the next death fails the job."""

    RESTARTS = 2

    def __init__(self, threads: int = DEFAULT_THREADS):
        self.threads = threads
        self._spec: tuple[Detector, Lens | None] | None = None
        self._names: list[str] | None = None
        self._loading = False
        self._reloading = False  # a replacement child's answer to the re-sent load is due before any frame's
        # frames (and their cameras) sent and not yet answered, oldest first
        self._flight: deque[tuple[np.ndarray, Lens | None]] = deque()
        self.restarts = 0
        self._start()

    def _start(self) -> None:
        # A plain `python -m garage_exp.perception.detect.worker` rather than multiprocessing: a spawn child re-imports the
        # parent's __main__ and inherits its start method, and inside a joblib (loky) worker that method is
        # "loky", which a spawn child cannot set up. Requests travel over a socket pair as pickles.
        ours, theirs = socket.socketpair()
        self._proc = subprocess.Popen([sys.executable, "-m", "garage_exp.perception.detect.worker", str(theirs.fileno()),
                                       str(self.threads)], pass_fds=(theirs.fileno(),))
        theirs.close()
        self._conn = Connection(ours.detach())

    def load(self, detector: Detector, probe: Lens | None = None) -> None:
        """Ask the child for this detector; returns at once (`names` waits for the load and raises its error).
        The same detector again is not checked again."""
        self.drain()
        self.restarts = 0
        if self._spec is not None and detector == self._spec[0] and not self._loading and self._names is not None:
            return
        self._spec, self._names, self._loading = (detector, probe), None, True
        self._send(("load", self._spec))

    @property
    def loaded(self) -> Detector | None:
        """The detector last asked for (`load`)."""
        return self._spec[0] if self._spec is not None else None

    @property
    def names(self) -> list[str]:
        """The models' names; waits for loading to finish (raises its GarageError)."""
        if self._loading:
            try:
                self._names = self._receive()
            finally:
                self._loading = False
        if self._names is None:
            raise RuntimeError("no detectors loaded: the last load failed")
        return self._names

    def submit(self, rgb: np.ndarray, intrinsics: Lens | None = None) -> None:
        self.names  # noqa: B018 - a loading error surfaces here, not as a frame's result
        self._flight.append((rgb, intrinsics))
        self._send(("detect", (rgb, intrinsics)))

    def result(self) -> list[Detections]:
        if not self._flight:
            raise RuntimeError("no detection pending")
        try:
            return self._receive()
        finally:
            if self._flight:  # answered (a GarageError is an answer too); empty if the child was discarded
                self._flight.popleft()

    def drain(self) -> None:
        """Read and drop unanswered answers (after a failed job), so the next job starts in step. Called while
        the job's own error propagates, so it raises nothing but a new Ctrl-C."""
        if not self.alive():  # no child to restart just to drop its answers: the next job starts a new one
            self._discard()
            return
        try:
            if self._loading:
                try:
                    self.names  # noqa: B018
                except GarageError:
                    pass
            while self._flight:
                try:
                    self.result()
                except GarageError:
                    pass
        except Exception:  # noqa: BLE001 - a dead or confused child: the next job starts a new one
            self._discard()

    def abandon(self) -> None:
        """Ctrl-C: stop the child now rather than wait for its frame or its models (a new one serves the next
        job)."""
        self._discard()

    @property
    def pid(self) -> int:
        return self._proc.pid

    def alive(self) -> bool:
        return self._proc.poll() is None

    def _discard(self) -> None:
        """Kill the child: after an interrupted exchange the pipe is out of step and cannot be trusted."""
        if STATE.detector is self:
            STATE.detector = None
        self._loading, self._reloading, self._names, self._spec = False, False, None, None
        self._flight.clear()
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self._conn.close()

    def close(self) -> None:
        if self._conn.closed:
            return
        try:
            self._conn.send(("exit", None))
        except (OSError, ValueError):
            pass
        try:
            self._proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._conn.close()

    def _send(self, message) -> None:
        try:
            self._conn.send(message)
        except (OSError, ValueError) as exc:
            self._revive(exc)  # the new child gets the load and every frame in flight, this one included
        except BaseException:  # Ctrl-C half-way through a frame
            self._discard()
            raise

    def _receive(self):
        while True:
            try:
                status, payload, records = self._conn.recv()
            except (EOFError, OSError) as exc:
                self._revive(exc)
                continue
            except BaseException:  # Ctrl-C half-way through an answer
                self._discard()
                raise
            for name, level, message in records:  # the child's log lines go where they would have in-process
                logging.getLogger(name).log(level, message)
            if self._reloading:  # the replacement loaded the job's detectors; the frames' answers follow
                self._reloading = False
                if status != "ok":
                    raise self._died(self._proc.poll())
                continue
            if status == "ok":
                return payload
            kind, message, where = payload
            if kind == "GarageError":
                raise GarageError(message, where)
            if kind == "JobFault":  # an expected fault (a model server gone): its one line, no traceback
                raise JobFault(message)
            raise RuntimeError(f"detector process: {kind}: {message}")

    def _exit_code(self) -> int | None:
        try:
            return self._proc.wait(timeout=5)  # the pipe breaks a moment before the process is reaped
        except subprocess.TimeoutExpired:  # alive with a broken pipe: out of step, of no further use
            self._proc.kill()
            return self._proc.wait()

    def _revive(self, cause: BaseException) -> None:
        """The child died: start another, load the job's detectors and re-send the frames in flight; raise
        (and fail the job) once RESTARTS replacements have died too."""
        while True:
            code = self._exit_code()
            if self.restarts >= self.RESTARTS or self._spec is None:
                raise self._died(code) from cause
            self.restarts += 1
            log.warning("the detector process died (exit code %s): started a new one and re-sent the %d frame(s) "
                        "in flight (restart %d of %d in this job)", code, len(self._flight), self.restarts,
                        self.RESTARTS)
            self._conn.close()
            self._start()
            self._reloading = not self._loading  # during a load, its answer is the one the caller waits for
            try:
                self._conn.send(("load", self._spec))
                for frame in self._flight:
                    self._conn.send(("detect", frame))
                return
            except (OSError, ValueError) as exc:
                cause = exc
            except BaseException:
                self._discard()
                raise

    def _died(self, code: int | None) -> RuntimeError:
        deaths = self.restarts + 1
        self._discard()  # the next job starts a new child
        times = f", {deaths} times in this job" if deaths > 1 else ""
        return RuntimeError(f"the detector process died (exit code {code}{times})")


def _serve(conn, threads: int) -> None:
    """The child's loop: one request, one answer, in order."""
    # Ctrl-C and SIGTERM (sent to the whole group by a terminal or a scheduler) are the parent's to handle: it
    # stops this child itself, and if it dies outright the pipe's end-of-file ends this loop.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    # The user's entry kinds ($GARAGE_EXP_PLUGINS), registered before a detector naming one arrives (the parent
    # imported them already, so they import here too).
    import_plugins()
    records = _Collect()
    log.addHandler(records)
    log.setLevel(logging.INFO)
    FILE_LOG.addHandler(records)  # the loaders' lines, for the parent's log file (core.logfile)
    detector = None
    while True:
        try:
            kind, payload = conn.recv()
        except (EOFError, OSError):
            return  # the parent is gone
        if kind == "exit":
            return
        try:
            if kind == "load":
                detector = None  # a failed load must not leave the previous job's detectors in place
                wanted, probe = payload
                loading = replace(wanted, threads=threads)
                loading.check(probe)
                detector, answer = loading, loading.names
            else:
                rgb, intrinsics = payload
                answer = detector.detect([rgb], [intrinsics])[0]
            reply = ("ok", answer)
        except GarageError as exc:
            reply = ("error", ("GarageError", message_of(exc), exc.where))
        except JobFault as exc:
            reply = ("error", ("JobFault", str(exc), None))
        except Exception as exc:  # noqa: BLE001 - reported to the parent, which raises it in the job
            reply = ("error", (type(exc).__name__, str(exc), None))
        conn.send((*reply, records.take()))


class _Collect(logging.Handler):
    """Keeps the child's log records for the next answer."""

    def __init__(self):
        super().__init__(logging.INFO)
        self._records: list[tuple[str, int, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self._records.append((record.name, record.levelno, record.getMessage()))

    def take(self) -> list[tuple[str, int, str]]:
        out, self._records = self._records, []
        return out


def configured_threads() -> int:
    raw = os.environ.get("GARAGE_EXP_OV_THREADS", str(DEFAULT_THREADS))
    try:
        return max(0, int(raw))
    except ValueError:
        raise GarageError(f"GARAGE_EXP_OV_THREADS must be an integer, got {raw!r}", "environment") from None


def use_process() -> bool:
    return os.environ.get("GARAGE_EXP_DETECT_PROCESS", "1").strip().lower() not in ("0", "false", "no")


def open_detector(detector: Detector, probe: Lens | None = None) -> DetectorProcess | InlineDetector:
    """The process's detector child, loading and checking `detector` (from `build_detector`; probe: the camera
    of the check's probe frame). The child is started on first use and reused by later jobs; `names` waits for
    the check and raises its error."""
    threads = configured_threads()
    if not use_process():
        return InlineDetector(detector, probe, threads=0)  # serial: nothing runs beside it, so all cores
    worker = STATE.detector
    if worker is not None and (not worker.alive() or worker.threads != threads):
        worker.close()
        worker = STATE.detector = None
    if worker is None:
        worker = STATE.detector = DetectorProcess(threads)
    worker.load(detector, probe)
    return worker


class WarmDetector:
    """A `Detector`'s batch interface (`detect`, `names`, `scoring`) on the process's one warm detector
    (`open_detector`): a caller outside the frame loop (the search's pre-screen) shares the job's child and its
    loaded models instead of loading them a second time in this process."""

    def __init__(self, detector: Detector, probe: Lens | None = None):
        self._detector, self._probe = detector, probe
        self._warm = open_detector(detector, probe)
        self.names = self._warm.names  # waits for the load: a detector that cannot load fails here (GarageError)

    def scoring(self) -> dict[str, tuple[str, ...]]:
        return self._detector.scoring()

    def detect(self, frames, intrinsics=None) -> list[list[Detections]]:
        batch = as_batch(frames)
        try:
            for rgb, cam in zip(batch, per_frame(intrinsics, len(batch))):
                self.submit(rgb, cam)
            return [self._warm.result() for _ in batch]
        except BaseException:
            self._warm.drain()  # the next caller starts in step
            raise

    # The frame pipeline's interface (run/pipeline.py `overlapped`): frame k detected while k + 1 renders.

    def submit(self, rgb, intrinsics: Lens | None = None) -> None:
        if self._warm.loaded != self._detector:  # a job's preflight loaded its own since
            self._warm.load(self._detector, self._probe)
        self._warm.submit(rgb, intrinsics)

    def result(self) -> list[Detections]:
        return self._warm.result()

    def drain(self) -> None:
        self._warm.drain()


@atexit.register
def _close_worker() -> None:
    if STATE.detector is not None:
        STATE.detector.close()  # without this the child still exits, on end-of-file, once this process is gone


if __name__ == "__main__":
    _serve(Connection(int(sys.argv[1])), int(sys.argv[2]))
