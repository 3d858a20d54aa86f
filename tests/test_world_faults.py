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
from conftest import PYTHON, child_env, compose_cfg, inject_fault, run_app, store_template
from mlflow_server import Server, free_port

from garage_exp.tracking import runs as tracking
from garage_exp.perception.detect import worker
from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE

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

    from garage_exp.perception.detect.detector import Detector

    return Detector(default_models()[:1], classes=("car", "truck", "bus"), conf=0.05, imgsz=320, device="cpu")


@pytest.fixture(scope="module")
def frames():
    from test_detect import bus_image

    _, rgb = bus_image()
    return [rgb, np.ascontiguousarray(rgb[::2, ::2]), np.ascontiguousarray(rgb[:, ::-1])]


def same(a, b):
    assert [d.model for d in a] == [d.model for d in b]
    for x, y in zip(a, b):
        np.testing.assert_allclose(x.scores, y.scores, atol=1e-6)
        np.testing.assert_allclose(x.boxes, y.boxes, atol=1e-3)


@pytest.mark.detect
def test_a_killed_detector_process_is_replaced_and_its_frames_sent_again(spec, frames, caplog):
    from dataclasses import replace

    expected = [replace(spec, threads=1).detect([f])[0] for f in frames]
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


# --- the sqlite store: two sweeps at once on a fresh one; one left broken -------------------------------------

def sweep_cmd(tmp: Path, name: str, *args: str) -> list[str]:
    return [PYTHON, "-m", "garage_exp", "-m", *DRY, *args, f"hydra.sweep.dir={tmp}/{name}",
            f"hydra.run.dir={tmp}/{name}_run"]


def store_runs(uri: str, experiment: str = "garage_exp"):
    mlc = tracking.client(uri)
    exp = mlc.get_experiment_by_name(experiment)
    return [] if exp is None else mlc.search_runs([exp.experiment_id], max_results=1000)


def test_sweeps_started_together_on_a_fresh_store_all_finish(tmp_path):
    """Two sweeps started at once on a store that does not exist yet (the first use, or the first after
    `make clean`): one creates MLflow's schema under the store's lock, the other waits for it. Without the
    lock one of the two crashed in each of 2 tries ("table latest_metrics already exists", "table
    _alembic_tmp_model_versions already exists"; with three, two crashed: "duplicate column name", "Online
    migration expected to match one row") and left the store broken."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    lights = ["bright", "dim"]
    procs = [subprocess.Popen(sweep_cmd(tmp_path, f"s{k}", f"light={light}", f"tracking.uri={uri}"), cwd=tmp_path,
                              env=child_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for k, light in enumerate(lights)]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0 and "Traceback" not in err, err[-3000:]
    runs = store_runs(uri)  # a later client opens the store as `make ui` would
    parents = [r for r in runs if r.data.tags.get("sweep") == "parent"]
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId")]
    assert len(parents) == 2 and len(children) == 2
    assert {r.info.status for r in runs} == {"FINISHED"}
    assert sorted(r.data.params["light.name"] for r in children) == sorted(lights)


def break_store(path: Path) -> None:
    """What an interrupted schema creation leaves: every table, but no recorded schema version, and
    alembic's half-done copy of a table."""
    with sqlite3.connect(path) as con:
        con.execute("delete from alembic_version")
        con.execute("create table _alembic_tmp_experiments (experiment_id integer)")


@pytest.fixture
def template() -> Path:
    return store_template()  # the session's migrated store: tests copy it, never write into it


def test_a_broken_store_is_one_line_naming_it_and_the_way_back(tmp_path, template):
    import hashlib
    import shutil

    db = tmp_path / "mlflow.db"
    shutil.copy(template, db)
    break_store(db)
    before = hashlib.sha256(db.read_bytes()).hexdigest()
    uri = f"sqlite:///{db}"
    proc = run_app(["-m", *DRY, f"tracking.uri={uri}"], tmp_path)
    line = one_line_error(proc.stderr)
    assert proc.returncode == 2
    assert line.startswith(f"garage_exp: {db}: broken MLflow store (schema found version None, but expected ")
    assert line.endswith(f"it holds no runs: delete it (rm {db}) and rerun (a store is created under a lock now, "
                         "so concurrent sweeps cannot break it again)")
    assert hashlib.sha256(db.read_bytes()).hexdigest() == before  # nothing written into it
    assert not (tmp_path / "sweep").exists()
    db.unlink()  # as the line says
    # The user's rerun is a new process, which starts without the engine this one's MLflow keeps for the URI (its
    # pooled connection still reads the deleted file): the engine is dropped, and the rerun runs here.
    from mlflow.store.tracking.sqlalchemy_store import SqlAlchemyStore

    SqlAlchemyStore._engine_map.pop(uri).dispose()
    again = run_app(["-m", *DRY, f"tracking.uri={uri}"], tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]


def runs_in_new(path: Path) -> int:
    from garage_exp.tracking.store import runs_in

    return runs_in(path)


def test_store_diagnosis_of_the_races_errors_and_of_a_store_with_runs(tmp_path, template):
    import shutil

    from garage_exp.tracking.store import diagnose, open_store

    empty = tmp_path / "empty.db"
    shutil.copy(template, empty)
    for message in ("(sqlite3.OperationalError) table _alembic_tmp_experiments already exists",
                    "Online migration expected to match one row when updating '867495a8f9d4' to '5b0e9adcef9c' in "
                    "'alembic_version'; 0 found", "(sqlite3.OperationalError) duplicate column name: step"):
        line = diagnose(empty, RuntimeError(message + "\n[SQL: ALTER TABLE ...]"))
        assert line.startswith("broken MLflow store (") and "delete it (rm " in line and "\n" not in line
    assert diagnose(empty, RuntimeError("database is locked")) is None  # not a broken store: retried elsewhere
    used = tmp_path / "used.db"
    shutil.copy(template, used)
    mlc = tracking.client(f"sqlite:///{used}")
    mlc.create_run(tracking.experiment_id(mlc, "garage_exp"))
    break_store(used)

    def fail():
        raise RuntimeError("Detected out-of-date database schema (found version None, but expected x). Take ...")

    with pytest.raises(GarageError) as err:
        open_store(f"sqlite:///{used}?fresh", fail)
    assert str(err.value) == (f"{used}: MLflow store cannot be opened (schema found version None, but expected x); "
                              f"it holds 1 runs: back it up (cp {used} {used}.bak), then run "
                              f"`mlflow db upgrade sqlite:///{used}`")
    from garage_exp.tracking.store import main as store_main  # what `make ui` runs before the UI

    shutil.copy(used, tmp_path / "copy.db")  # not opened by this process yet (MLflow caches opened stores)
    assert store_main([str(tmp_path / "copy.db")]) == 2
    assert store_main([str(tmp_path / "new.db")]) == 0 and runs_in_new(tmp_path / "new.db") == 0
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"not sqlite at all" * 100)
    with pytest.raises(GarageError, match="not an MLflow sqlite store"):
        tracking.client(f"sqlite:///{junk}")


# --- a full disk ------------------------------------------------------------------------------------------------

@pytest.fixture
def small_fs(tmp_path):
    """A 16 MB tmpfs (as root, where mounting works), else a plain directory: the full disk is then faked by a
    plan-map writer that raises ENOSPC (tests/faults/sitecustomize.py `disk:raise`)."""
    fs = tmp_path / "fs"
    fs.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(fs)],
                             capture_output=True).returncode == 0 if os.geteuid() == 0 else False
    yield fs, mounted
    if mounted:
        subprocess.run(["umount", "-l", str(fs)], check=True)


FAULTS = os.pathsep.join([str(Path(__file__).resolve().parent / "faults"),
                         *filter(None, [os.environ.get("PYTHONPATH")])])
LIGHTS = "light=bright,dim,clear,moderate"


def test_a_full_disk_stops_the_sweep_in_one_line_keeping_the_finished_runs(small_fs, template, monkeypatch):
    """Four jobs writing to a small filesystem that job 2 fills: jobs 0 and 1 are kept whole, job 2's run ends
    FAILED saying the disk is full (the store shares the disk, so job 2's partial files are deleted to make
    room for that), job 3 does not start, nothing stays RUNNING, one line, exit 1; once there is space,
    resume=true finishes the sweep. The sweep runs in this process, the fault injected as GARAGE_EXP_FAULT
    injects it in a new one (the disk, not the process, is the subject)."""
    import shutil

    fs, mounted = small_fs
    shutil.copy(template, fs / "mlflow.db")
    uri = f"sqlite:///{fs / 'mlflow.db'}"
    args = ["-m", *DRY, LIGHTS, f"tracking.uri={uri}", f"hydra.sweep.dir={fs}/sweep"]
    with monkeypatch.context() as faulty:
        inject_fault(faulty, "disk:fill:2" if mounted else "disk:raise:2")
        proc = run_app(args, fs)
    line = one_line_error(proc.stderr)
    assert proc.returncode == 1
    assert line.startswith(f"garage_exp: disk full at {fs}/sweep/2")
    assert line.endswith(": 2 of 4 jobs finished; free space and rerun with resume=true")
    assert len([ln for ln in proc.stderr.splitlines() if "disk full" in ln]) == 1
    runs = store_runs(uri)
    jobs = {r.data.params["light.name"]: r for r in runs if r.data.tags.get("mlflow.parentRunId")}
    parent = next(r for r in runs if r.data.tags.get("sweep") == "parent")
    assert set(jobs) == {"bright", "dim", "clear"}  # moderate never started
    assert jobs["bright"].info.status == jobs["dim"].info.status == "FINISHED"
    assert jobs["clear"].info.status == "FAILED" and jobs["clear"].data.tags["error"].startswith("disk full at")
    assert parent.info.status == "FAILED" and "disk full" in parent.data.tags["error"]
    for k in (0, 1):  # the finished jobs' files and their artifacts are whole
        assert (fs / "sweep" / str(k) / "plan_map.png").stat().st_size > 10_000
    for name in ("bright", "dim"):
        arts = {a.path for a in tracking.client(uri).list_artifacts(jobs[name].info.run_id)}
        assert arts == {"config.yaml", "plan_map.png"}
    if mounted:  # the store shared the full disk: job 2's own files made room to record its failure
        assert "partial outputs were deleted" in jobs["clear"].data.tags["error"]
        assert not (fs / "sweep" / "2" / "filler").exists()
    again = run_app([*args, "resume=true"], fs)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "2 finished, 2 skipped (finished before), 0 failed" in again.stdout


def test_preflight_refuses_a_sweep_the_free_space_cannot_hold(tmp_path, monkeypatch):
    """A four-job sweep whose filesystem has 1 MB free: the sweep's own check (the callback's check_sweep, with
    preflight's estimate of each job) refuses it in one line naming the directory, exit 2, nothing written.
    The free-space probe reports 1 MB for this directory only, so the check is reached on any machine; the
    command line runs in a child forked from this process (it inherits the patched probe)."""
    import shutil

    from garage_exp.run import diskspace
    from garage_exp.run.preflight import job_bytes

    fs = tmp_path / "fs"
    fs.mkdir()
    real_usage = shutil.disk_usage
    monkeypatch.setattr(diskspace.shutil, "disk_usage", lambda path: shutil_usage(free=1 << 20)
                        if Path(path).absolute().is_relative_to(fs) else real_usage(path))
    uri = f"sqlite:///{fs}/mlflow.db"
    args = [*DRY, LIGHTS, f"tracking.uri={uri}"]
    out, store = job_bytes(compose_cfg(*DRY, f"tracking.uri={uri}"), None, None)  # a plan-only job's estimate
    assert out > 0 and store > out
    proc = run_app(["-m", *args], fs, fresh_store=True)
    line = one_line_error(proc.stderr)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert line == (f"garage_exp: {fs}: not enough free disk space: the sweep (4 jobs) will write about "
                    f"{diskspace.mb(4 * (out + store))} on this filesystem and 1.0 MB is free; free some space, or "
                    "write elsewhere (hydra.sweep.dir=..., tracking.uri=...), or save fewer frames "
                    "(renderer.save_frames=key)")
    assert [p for p in fs.rglob("*") if p.is_file()] == []  # no store, no job's files
    # check_free itself: directories on one filesystem add up.
    monkeypatch.setattr(diskspace.shutil, "disk_usage", lambda path: shutil_usage(free=3 << 20))
    diskspace.check_free([(fs, 1 << 20), (fs / "store", 1 << 20)], "the sweep (2 jobs)")  # 2 MB fit in 3
    with pytest.raises(GarageError, match=r"the sweep \(3 jobs\) will write about 4.0 MB on this filesystem and "
                                          r"3.0 MB is free"):
        diskspace.check_free([(fs, 3 << 20), (fs / "not" / "yet", 1 << 20)], "the sweep (3 jobs)")


def shutil_usage(free: int):
    import shutil

    return shutil._ntuple_diskusage(16 << 20, (16 << 20) - free, free)


def test_a_full_disk_is_recognised_whoever_raised_it():
    import errno

    from garage_exp.run.diskspace import full_disk

    assert full_disk(OSError(errno.ENOSPC, "No space left on device", "/x/frames.csv")) == "/x/frames.csv"
    wrapped = RuntimeError("MlflowException: (sqlite3.OperationalError) database or disk is full")
    assert full_disk(wrapped) == ""
    try:
        try:
            raise OSError(errno.EDQUOT, "Disk quota exceeded")
        except OSError as inner:
            raise ValueError("could not save the figure") from inner
    except ValueError as outer:
        assert full_disk(outer) == ""
    assert full_disk(OSError(errno.EACCES, "Permission denied")) is None
    assert full_disk(RuntimeError("boom")) is None


# --- the tracking server goes away ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """One server for the module (starting one takes 10-30 s here); each test logs to its own experiment and
    leaves the server running."""
    srv = Server(tmp_path_factory.mktemp("server"))
    srv.start()
    yield srv
    srv.stop()


def start_sweep(tmp: Path, args: list[str], env: dict) -> subprocess.Popen:
    return subprocess.Popen([PYTHON, "-m", "garage_exp", *args, f"hydra.sweep.dir={tmp}/sweep"], cwd=tmp,
                            env=child_env({"PYTHONPATH": FAULTS, "GARAGE_EXP_FAULT_GO": str(tmp / "go"), **env}),
                            stdout=open(tmp / "out.txt", "w"), stderr=open(tmp / "err.txt", "w"),
                            start_new_session=True)


def wait_for_text(path: Path, text: str, proc: subprocess.Popen, timeout: float = 180) -> None:
    deadline = time.monotonic() + timeout
    while text not in path.read_text():
        assert proc.poll() is None, (path.parent / "err.txt").read_text()[-3000:]
        assert time.monotonic() < deadline, f"timed out waiting for {text!r}"
        time.sleep(0.2)


def test_sigterm_ends_a_sweep_within_seconds_whatever_the_server_does(tmp_path, server):
    """The server hangs (SIGSTOP: connections are accepted, nothing answers) while a job logs to it, with a
    wait of ten minutes allowed: SIGTERM still ends the sweep in seconds, with one line and exit 143."""
    env = {"MLFLOW_TRACKING_URI": server.uri, "GARAGE_EXP_TRACKING_WAIT": "600", "GARAGE_EXP_FAULT": "map:wait:0"}
    proc = start_sweep(tmp_path, ["-m", *DRY, "light=bright,dim", "tracking.experiment=hung"], env)
    wait_for_text(tmp_path / "out.txt", "FAULT: job 0 waits", proc)
    os.killpg(server.proc.pid, signal.SIGSTOP)
    try:
        (tmp_path / "go").touch()
        time.sleep(3)  # the job is now blocked in a request to the hung server
        assert proc.poll() is None
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
        took = time.monotonic() - sent
    finally:
        os.killpg(server.proc.pid, signal.SIGCONT)
    print(f"SIGTERM to exit: {took:.1f} s")
    line = one_line_error((tmp_path / "err.txt").read_text())
    assert code == 143
    assert line == "garage_exp: terminated (SIGTERM); rerun the same command with resume=true to finish the sweep"
    assert took < 15, took  # 4.9 s measured on 2 loaded cores; before: over 15 minutes
    assert (tmp_path / "sweep" / "0" / "plan_map.png").is_file()  # the job's files are kept


def test_a_tracking_server_gone_mid_sweep_keeps_the_outputs_and_resume_logs_them(tmp_path, server):
    """The server dies while job 1 runs: job 1 waits for it (one line), gives up after the wait
    ($GARAGE_EXP_TRACKING_WAIT, 3 s here), finishes its files, keeps the calls the server missed, and the sweep
    stops (one line, exit 1). With the server back, resume=true logs job 1 into its own run from the kept
    files without running it again, and runs job 2."""
    env = {"MLFLOW_TRACKING_URI": server.uri, "GARAGE_EXP_TRACKING_WAIT": "3", "GARAGE_EXP_FAULT": "map:wait:1"}
    args = ["-m", *DRY, "light=bright,dim,clear", "tracking.experiment=away"]
    proc = start_sweep(tmp_path, args, env)
    wait_for_text(tmp_path / "out.txt", "FAULT: job 1 waits", proc)
    server.stop()
    (tmp_path / "go").touch()
    assert proc.wait(timeout=120) == 1
    err = (tmp_path / "err.txt").read_text()
    line = one_line_error(err)
    job1 = tmp_path / "sweep" / "1"
    assert line.startswith(f"garage_exp: tracking server {server.uri} away: job 'dry_run=True plan=tiny light=dim' "
                           f"finished, its outputs kept in {job1}: 1 of 3 jobs finished; rerun the same command")
    waiting = [ln for ln in err.splitlines() if "not answering" in ln]
    assert waiting == [f"garage_exp: tracking server {server.uri} not answering; retrying for up to 3 s "
                       "(GARAGE_EXP_TRACKING_WAIT)"]
    assert (job1 / "plan_map.png").is_file() and (job1 / tracking.PENDING_FILE).is_file()
    drawn = (job1 / "plan_map.png").stat().st_mtime_ns
    assert not (tmp_path / "sweep" / "2" / "plan_map.png").exists()  # the sweep stopped

    server.start()
    again = run_app([*args, "resume=true"], tmp_path, env={"MLFLOW_TRACKING_URI": server.uri})  # in this process
    assert again.returncode == 0, again.stderr[-3000:]
    assert f"from the outputs kept in {job1} (run " in again.stdout and "not rendered again" in again.stdout
    assert (job1 / "plan_map.png").stat().st_mtime_ns == drawn  # not drawn again
    runs = store_runs(server.uri, "away")
    jobs = {r.data.params["light.name"]: r for r in runs if r.data.tags.get("mlflow.parentRunId")}
    assert sorted(jobs) == ["bright", "clear", "dim"] and len(runs) == 4  # one parent, no duplicate runs
    assert {r.info.status for r in runs} == {"FINISHED"}
    arts = {a.path for a in tracking.client(server.uri).list_artifacts(jobs["dim"].info.run_id)}
    assert arts == {"config.yaml", "plan_map.png"}


def test_a_job_run_keeps_what_the_server_missed_and_resume_replays_it(tmp_path, template, fresh_outage, monkeypatch):
    import shutil

    from omegaconf import OmegaConf

    shutil.copy(template, tmp_path / "mlflow.db")
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    mlc = tracking.client(uri)
    run_id = mlc.create_run(tracking.experiment_id(mlc, "garage_exp"), tags={"config_hash": "h",
                                                                            "output_dir": str(tmp_path)}).info.run_id
    monkeypatch.setattr(STATE, "tracking_given_up", True)  # the server is away
    run = tracking.JobRun(mlc, run_id, pending=tmp_path / tracking.PENDING_FILE)
    (tmp_path / "table.csv").write_text("a\n1\n")
    run.log_series("confidence", [0.5, 0.25])
    run.log_metrics({"recall": 1.0})
    run.log_artifact(tmp_path / "table.csv")
    run.end("FINISHED")
    assert run.kept == 4 and mlc.get_run(run_id).info.status == "RUNNING"
    monkeypatch.setattr(STATE, "tracking_given_up", False)  # it is back
    cfg = OmegaConf.create({"tracking": {"uri": uri, "experiment": "garage_exp"}})
    kept = tracking.kept_run(cfg, "h")
    assert kept == (run_id, tmp_path / tracking.PENDING_FILE)
    tracking.replay_pending(cfg, *kept)
    got = mlc.get_run(run_id)
    assert got.info.status == "FINISHED" and got.data.metrics == {"confidence": 0.25, "recall": 1.0}
    assert [m.value for m in mlc.get_metric_history(run_id, "confidence")] == [0.5, 0.25]
    assert [a.path for a in mlc.list_artifacts(run_id)] == ["table.csv"]
    assert tracking.kept_run(cfg, "h") is None  # logged once


def test_a_server_that_is_away_when_the_sweep_starts_is_one_line(tmp_path):
    """Nothing listens on the port: the sweep waits the allowed time (1 s here), then says so in one line,
    exit 1, nothing logged anywhere."""
    uri = f"http://127.0.0.1:{free_port()}"
    proc = run_app(["-m", *DRY, "light=bright,dim"], tmp_path,
                   env={"MLFLOW_TRACKING_URI": uri, "GARAGE_EXP_TRACKING_WAIT": "1"})
    line = one_line_error(proc.stderr)
    assert proc.returncode == 1
    assert line.startswith(f"garage_exp: tracking server {uri} away for ")
    assert line.endswith(" s; rerun the same command with resume=true once the server is back")
    assert not (tmp_path / "sweep" / "0").exists()
