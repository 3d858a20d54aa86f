"""Sweeps that are killed, resumed, interrupted, or run by parallel workers (issue 5). Plan-only jobs
(dry_run=true) keep these fast; tests/faults/sitecustomize.py makes a chosen job hang or raise."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from conftest import PYTHON, child_env, run_app, store_template

from garage_exp.tracking import runs as tracking

# The fault-injection hooks, ahead of the caller's own PYTHONPATH (a work tree testing its own garage_exp).
FAULTS = os.pathsep.join([str(Path(__file__).resolve().parent / "faults"),
                         *filter(None, [os.environ.get("PYTHONPATH")])])
SWEEP = ["-m", "dry_run=true", "plan=tiny", "light=bright,dim,clear"]


def all_runs(uri: str, deleted: bool = False):
    from mlflow.entities import ViewType

    mlc = tracking.client(uri)
    exp = mlc.get_experiment_by_name("garage_exp")
    if exp is None:
        return mlc, []
    view = ViewType.ALL if deleted else ViewType.ACTIVE_ONLY
    return mlc, mlc.search_runs([exp.experiment_id], max_results=1000, run_view_type=view)


def start_sweep(args: list[str], tmp: Path, env: dict) -> subprocess.Popen:
    """The sweep in its own session (process group), as a user's shell would start it."""
    cmd = [PYTHON, "-m", "garage_exp", *args, f"hydra.run.dir={tmp}/run", f"hydra.sweep.dir={tmp}/sweep"]
    return subprocess.Popen(cmd, cwd=tmp, env=child_env(env), stdout=open(tmp / "first.out", "w"),
                            stderr=subprocess.STDOUT, start_new_session=True)


def wait_for(predicate, proc: subprocess.Popen, timeout: float = 180):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        assert proc.poll() is None, "the sweep ended before the state to wait for"
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.3)


def job_runs(runs):
    return [r for r in runs if r.data.tags.get("mlflow.parentRunId")]


@pytest.fixture
def fresh_store(tmp_path) -> str:
    """A new, empty store for one test (a copy of the session's migrated template, conftest.store_template: no
    experiment, the app creates it, so its artifacts go where they would for a user)."""
    import shutil

    shutil.copy(store_template(), tmp_path / "mlflow.db")
    return f"sqlite:///{tmp_path / 'mlflow.db'}"


JOB_OF = {"bright": 0, "dim": 1, "clear": 2}  # SWEEP's job numbers


def hanging(uri: str, sweep_dir: Path, light: str):
    """The job of that light level is running, hanging in the fault (its line printed: a signal now lands in the
    fault's sleep, as it would in a long render, not somewhere the job is still starting), and the ones before
    it finished."""
    if not (sweep_dir / tracking.PARENT_FILE).exists():
        return None  # the sweep is still opening its parent run: do not race it
    out = sweep_dir.parent / "first.out"
    if f"FAULT: job {JOB_OF[light]} hangs" not in (out.read_text() if out.exists() else ""):
        return None
    _, runs = all_runs(uri)
    jobs = job_runs(runs)
    running = [r for r in jobs if r.info.status == "RUNNING"]
    # .get: a run just created may not have logged its params yet (polled again next time).
    if len(running) == 1 and running[0].data.params.get("light.name") == light:
        return running[0]
    return None


def signal_while_hanging(proc: subprocess.Popen, uri: str, sweep_dir: Path, light: str, sig: int):
    """Send sig to the sweep once the job of that light level hangs; (that job's run, the exit code)."""
    try:
        run = wait_for(lambda: hanging(uri, sweep_dir, light), proc)
        os.kill(proc.pid, sig)
        try:
            return run, proc.wait(timeout=120)
        except subprocess.TimeoutExpired:  # say where it was: its output so far
            pytest.fail(f"no exit 120 s after signal {sig}:\n{(sweep_dir.parent / 'first.out').read_text()[-3000:]}")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def test_kill_9_then_sigterm_then_resume(tmp_path, fresh_store):
    """A sweep of three jobs is killed with SIGKILL half-way; resumed, it is stopped by SIGTERM (a scheduler's
    time limit) in its last job; resumed again, it completes. Finished jobs are never rerun, unfinished ones
    are, and the store ends with one parent and one finished run per job: no duplicates, nothing RUNNING."""
    uri = fresh_store
    args = [*SWEEP, f"tracking.uri={uri}"]
    # 1. kill -9 while job 1 runs: nobody can close anything.
    proc = start_sweep(args, tmp_path, {"PYTHONPATH": FAULTS, "GARAGE_EXP_FAULT": "map:hang:1"})
    try:
        killed = wait_for(lambda: hanging(uri, tmp_path / "sweep", "dim"), proc)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    mlc, runs = all_runs(uri)
    parent = next(r for r in runs if r.data.tags.get("sweep") == "parent")
    assert parent.info.status == "RUNNING" and killed.info.status == "RUNNING"
    finished = [j for j in job_runs(runs) if j.info.status == "FINISHED"]
    assert [j.data.params["light.name"] for j in finished] == ["bright"]
    first_id = finished[0].info.run_id

    # 2. resume=true: job 0 is skipped, job 1 reruns (its stale run superseded), job 2 gets SIGTERM.
    proc = start_sweep([*args, "resume=true"], tmp_path, {"PYTHONPATH": FAULTS, "GARAGE_EXP_FAULT": "map:hang:2"})
    terminated, rc = signal_while_hanging(proc, uri, tmp_path / "sweep", "clear", signal.SIGTERM)
    out = (tmp_path / "first.out").read_text()
    assert rc == 128 + signal.SIGTERM, out[-3000:]
    assert f"finished before as run {first_id}" in out
    assert f"replaces unfinished run(s) {killed.info.run_id}" in out
    assert "terminated (SIGTERM)" in out and "Traceback" not in out
    assert mlc.get_run(terminated.info.run_id).info.status == "KILLED"  # not left RUNNING
    stopped = mlc.get_run(parent.info.run_id)
    assert stopped.info.status == "KILLED" and "sweep interrupted" in stopped.data.tags["error"]
    gone = mlc.get_run(killed.info.run_id)  # the kill -9 victim: KILLED, replaced, deleted (restorable)
    assert gone.info.status == "KILLED" and gone.info.lifecycle_stage == "deleted"
    assert gone.data.tags["superseded_by"]

    # 3. resume=true again: jobs 0 and 1 are skipped, job 2 reruns; the sweep completes.
    r = run_app([*args, "resume=true"], tmp_path)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    assert "sweep summary: 3 jobs: 1 finished, 2 skipped (finished before), 0 failed" in r.stdout
    mlc, runs = all_runs(uri)
    parents = [x for x in runs if x.data.tags.get("sweep") == "parent"]
    jobs = job_runs(runs)
    assert [x.info.run_id for x in parents] == [parent.info.run_id]  # the same parent, reopened twice
    assert parents[0].info.status == "FINISHED" and parents[0].data.tags["resumes"] == "2"
    assert len(runs) == 4 and len(jobs) == 3 and all(j.info.status == "FINISHED" for j in jobs)
    assert len({j.data.tags["config_hash"] for j in jobs}) == 3
    assert {j.data.tags["mlflow.parentRunId"] for j in jobs} == {parent.info.run_id}
    assert sorted(j.data.params["light.name"] for j in jobs) == ["bright", "clear", "dim"]
    assert first_id in {j.info.run_id for j in jobs}  # the job finished before the kill was never rerun
    _, everything = all_runs(uri, deleted=True)
    assert not [x for x in everything if x.info.status == "RUNNING"]
    report = (tmp_path / "sweep" / "report" / "report.md").read_text()
    assert "3 runs, 0 not finished, 2 skipped" in report and first_id in report


def test_resume_reruns_a_job_whose_plan_file_was_edited(tmp_path, fresh_store):
    """resume=true skips a finished job; after the plan file is edited, the same command reruns it."""
    plan = tmp_path / "mine.yaml"
    cells = "S: [[0, 0, 0, -1], [2, 1, 1, 0], [0, 0, 1, 0], [-1, 0, 3, -1]]\nR: [5, 6, 5, 5]\n"  # the tiny plan's
    plan.write_text(cells + "C: [2.6, 2.6, 6, 2.6]\n")  # (a dry run builds case 1's scene: it needs the corner)
    args = ["-m", "dry_run=true", f"plan.file={plan}", "light=bright", f"tracking.uri={fresh_store}", "resume=true"]
    first = run_app(args, tmp_path)
    assert first.returncode == 0, first.stderr[-3000:]
    again = run_app(args, tmp_path)
    assert "sweep summary: 1 jobs: 0 finished, 1 skipped (finished before), 0 failed" in again.stdout, again.stdout
    plan.write_text(cells + "C: [2.6, 2.6, 6.2, 2.6]\n")  # a wider lane: another garage
    edited = run_app(args, tmp_path)
    assert edited.returncode == 0, edited.stderr[-3000:]
    # Rerun, not skipped. (The summary's "finished" count also holds the old plan's run, still a child of the
    # same parent: "1 jobs: 2 finished"; reported to the lead, not pinned here.)
    assert "0 skipped (finished before), 0 failed" in edited.stdout, edited.stdout
    _, runs = all_runs(fresh_store)
    jobs = job_runs(runs)
    assert len(jobs) == 2 and len({j.data.tags["config_hash"] for j in jobs}) == 2
    assert all(j.info.status == "FINISHED" for j in jobs)


def test_sigterm_inside_a_store_write_exits_at_once_and_leaves_nothing_running(tmp_path, fresh_store):
    """SIGTERM that lands inside the MLflow session logging a job's params (tests/faults `store:term`): the write
    completes, the job's run ends KILLED (not RUNNING), exit 143 with one line, no traceback. Before the signal
    was held there, the run stayed RUNNING, and under load the stop waited out sqlite's busy timeout (CI: no exit
    within a minute)."""
    uri = fresh_store
    proc = start_sweep([*SWEEP, f"tracking.uri={uri}"], tmp_path, {"PYTHONPATH": FAULTS,
                                                                   "GARAGE_EXP_FAULT": "store:term:1"})
    rc = proc.wait(timeout=180)
    out = (tmp_path / "first.out").read_text()
    assert "FAULT: job 1 gets SIGTERM inside a store session" in out
    assert rc == 128 + signal.SIGTERM and "terminated (SIGTERM)" in out and "Traceback" not in out, out[-3000:]
    _, runs = all_runs(uri)
    assert not [r for r in runs if r.info.status == "RUNNING"]
    jobs = job_runs(runs)
    assert sorted(j.info.status for j in jobs) == ["FINISHED", "KILLED"]


def test_ctrl_c_exits_130_and_leaves_nothing_running(tmp_path, fresh_store):
    """SIGINT (Ctrl-C) in a running job: exit code 130, one line saying how to resume, no run left RUNNING."""
    uri = fresh_store
    proc = start_sweep([*SWEEP, f"tracking.uri={uri}"], tmp_path, {"PYTHONPATH": FAULTS,
                                                                   "GARAGE_EXP_FAULT": "map:hang:1"})
    _, rc = signal_while_hanging(proc, uri, tmp_path / "sweep", "dim", signal.SIGINT)
    out = (tmp_path / "first.out").read_text()
    assert rc == 130, out[-3000:]
    assert "garage_exp: interrupted; rerun the same command with resume=true" in out
    assert "Traceback" not in out
    _, everything = all_runs(uri, deleted=True)
    assert everything and not [x for x in everything if x.info.status == "RUNNING"]


def test_joblib_two_workers_log_every_run_under_the_parent(tmp_path, fresh_store):
    """Two worker processes share one sqlite store: every run is logged (params, tags, artifacts), every job
    is a child of the sweep's parent, and the two workers really ran at once."""
    uri = fresh_store
    r = run_app(["-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "dry_run=true", "plan=tiny",
                 "light=bright,dim,clear,moderate", f"tracking.uri={uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "locked" not in (r.stdout + r.stderr).lower()
    mlc, runs = all_runs(uri)
    parents = [x for x in runs if x.data.tags.get("sweep") == "parent"]
    jobs = job_runs(runs)
    assert len(parents) == 1 and len(jobs) == 4 and len(runs) == 5
    assert parents[0].info.status == "FINISHED"
    assert {j.data.tags["mlflow.parentRunId"] for j in jobs} == {parents[0].info.run_id}
    assert all(j.info.status == "FINISHED" for j in jobs)
    assert sorted(j.data.params["light.name"] for j in jobs) == ["bright", "clear", "dim", "moderate"]
    pids = {j.data.tags["pid"] for j in jobs}
    assert len(pids) == 2 and parents[0].data.tags["pid"] not in pids  # two workers, neither the parent
    # Each worker's span (its first run's start to its last run's end): the two spans overlap in time.
    spans = [(min(j.info.start_time for j in jobs if j.data.tags["pid"] == pid),
              max(j.info.end_time for j in jobs if j.data.tags["pid"] == pid)) for pid in pids]
    (a0, a1), (b0, b1) = spans
    assert max(a0, b0) < min(a1, b1), spans
    for j in jobs:
        assert {"config.yaml", "plan_map.png"} <= {a.path for a in mlc.list_artifacts(j.info.run_id)}
    assert "sweep summary: 4 jobs: 4 finished" in r.stdout


# ---------------------------------------------------------------------------------------------- unit level

class Locked(Exception):
    pass


def test_retry_rides_out_database_is_locked():
    calls = []

    def flaky():
        calls.append(1)
        if len(calls) < 3:
            raise Locked("(sqlite3.OperationalError) database is locked")
        return "ok"

    assert tracking.retry(flaky, base_delay=0.001) == "ok" and len(calls) == 3


def test_retry_gives_up_and_does_not_retry_other_errors():
    calls = []

    def broken():
        calls.append(1)
        raise ValueError("no such table")

    with pytest.raises(ValueError):
        tracking.retry(broken, base_delay=0.001)
    assert len(calls) == 1
    always = []

    def locked():
        always.append(1)
        raise Locked("database is locked")

    with pytest.raises(Locked):
        tracking.retry(locked, attempts=4, base_delay=0.001)
    assert len(always) == 4


def test_job_run_logging_goes_through_retry(tmp_path, fresh_store):
    """Every write of a job's run survives a locked store (here: the first two attempts of each call fail)."""
    mlc = tracking.client(fresh_store)
    run = mlc.create_run(mlc.create_experiment("locked", artifact_location=str(tmp_path / "artifacts")))
    real = {name: getattr(mlc, name) for name in ("log_batch", "set_tag", "log_metric", "set_terminated")}
    failures = {name: 2 for name in real}

    def flaky(name):
        def call(*args, **kwargs):
            if failures[name]:
                failures[name] -= 1
                raise Locked("database is locked")
            return real[name](*args, **kwargs)
        return call

    for name in real:
        setattr(mlc, name, flaky(name))
    job = tracking.JobRun(mlc, run.info.run_id)
    import garage_exp.tracking.runs as t

    delay = t.retry.__defaults__
    t.retry.__defaults__ = (10, 0.001, 0.01)
    try:
        job.log_metrics({"a": 1.0, "b": 2.0})
        job.set_tag("k", "v")
        job.log_metric("c", 3.0)
        job.end("FINISHED")
    finally:
        t.retry.__defaults__ = delay
    got = real["log_batch"].__self__.get_run(run.info.run_id)
    assert got.data.metrics == {"a": 1.0, "b": 2.0, "c": 3.0} and got.data.tags["k"] == "v"
    assert got.info.status == "FINISHED"


def test_a_job_whose_process_died_does_not_stay_running(tmp_path, fresh_store):
    """At a sweep's end every job has returned: a child run still RUNNING lost its process (OOM killer,
    segfault in a worker) and is closed FAILED with that reason, so the UI never shows a dead job as alive."""
    from garage_exp.cli.callbacks import close_dead_children

    mlc = tracking.client(fresh_store)
    exp = mlc.create_experiment("dead", artifact_location=str(tmp_path / "artifacts"))
    parent = mlc.create_run(exp, tags={"sweep": "parent"})
    alive = mlc.create_run(exp, tags={"mlflow.parentRunId": parent.info.run_id})
    done = mlc.create_run(exp, tags={"mlflow.parentRunId": parent.info.run_id})
    mlc.set_terminated(done.info.run_id, "FINISHED")
    close_dead_children(mlc, parent.info.run_id)
    dead = mlc.get_run(alive.info.run_id)
    assert dead.info.status == "FAILED" and "ended without closing" in dead.data.tags["error"]
    assert mlc.get_run(done.info.run_id).info.status == "FINISHED"
