"""A sweep and a search on a real local cluster (`hydra/launcher=ray`): a throw-away PostgreSQL behind Optuna and
an MLflow server, a Ray head and a second Ray node, all on localhost (tests/cluster.py). The faults are real: the
second node is killed mid-sweep, PostgreSQL is stopped for a few seconds mid-search."""

import re
import threading
import time

import optuna
import pytest
from cluster import Postgres, mlflow_server, ray_node, ray_nodes_up, wait_for
from conftest import require, run_app
from optuna.trial import TrialState

from garage_exp.tracking import runs as tracking

pytestmark = [pytest.mark.cluster, pytest.mark.slow, pytest.mark.render, pytest.mark.detect]
SMALL = ["plan=tiny", "case.motion.start=5", "case.motion.end=5", "camera.width=320", "camera.height=240",
         "detector.imgsz=320"]  # one frame a job: the jobs, not their frames, are what the cluster tests count


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    require("cluster", "vulkan", "vehicles", "models")
    import tempfile
    from pathlib import Path

    root = tmp_path_factory.mktemp("cluster")
    ray_root = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # Ray's socket paths must stay short
    pg, procs = Postgres(), []
    c = {"root": root, "pg": pg, "procs": procs}
    try:  # each server starts while the test waits for another: the Ray head during PostgreSQL's initdb, the
        # second node while the MLflow server comes up
        head, address = ray_node(ray_root, "head")
        procs.append(head)
        pg.init("mlflow", "optuna")
        ray_nodes_up(address, 1)
        second, _ = ray_node(ray_root, "second", address)
        procs.append(second)
        server, uri = mlflow_server(root, pg.url("mlflow"), root / "artifacts")
        procs.append(server)
        ray_nodes_up(address, 2)
        c.update(address=address, uri=uri, optuna=pg.url("optuna"), head=head, second=second, ray_root=ray_root)
        yield c
    finally:  # every path: each process we started, by its process group
        for p in procs:
            p.kill()
        pg.kill()
        import shutil

        shutil.rmtree(ray_root, ignore_errors=True)


def drive(args: list[str], tmp_path, env: dict | None = None):
    """The command line in this process (run_app), as the cluster's driver: the cluster, not the driver's
    interpreter, is the subject. Ray's driver is left after it (the sweep leaves it on every normal path) and
    the SIGTERM handler ray.init installs is put back, for the worker's later tests."""
    import signal

    import ray

    handler = signal.getsignal(signal.SIGTERM)
    try:
        return run_app(args, tmp_path, env=env)
    finally:
        if ray.is_initialized():
            ray.shutdown()
        signal.signal(signal.SIGTERM, handler)


def on_cluster(c, experiment: str) -> list[str]:
    """The cluster's Ray and MLflow server, each test's runs in an experiment of its own."""
    return ["hydra/launcher=ray", f"hydra.launcher.address={c['address']}", f"tracking.uri={c['uri']}",
            f"tracking.experiment={experiment}"]


def child_runs(uri: str, experiment: str) -> list:
    mlc = tracking.client(uri)
    exp = mlc.get_experiment_by_name(experiment)
    if exp is None:
        return []
    return [r for r in mlc.search_runs([exp.experiment_id], max_results=200) if r.data.tags.get("sweep") != "parent"]


def test_a_search_on_two_nodes_waits_out_a_database_restart(cluster, tmp_path):
    """2 workers (Ray tasks) share one PostgreSQL study of 4 trials; PostgreSQL is stopped for 5 s once the
    study has its first result: each trial is there once with one finished run, the parent holds the search
    report, and the wait was one line, not a traceback. It runs before the sweep that kills the second node
    (a node is started again if that sweep ran first)."""
    from cluster import ray_node as start_node

    if cluster["second"].proc.poll() is not None or not cluster["second"].pids():
        second, _ = start_node(cluster["ray_root"], "second_again", cluster["address"])
        cluster["procs"].append(second)
        ray_nodes_up(cluster["address"], 2)
    pg, url = cluster["pg"], cluster["optuna"]
    paused = {}

    def pause_the_database_once_a_trial_is_told():
        def told():  # one short connection a poll: engines left open by polling would fill max_connections
            import psycopg

            with psycopg.connect(url, connect_timeout=5) as con:
                return con.execute("SELECT count(*) FROM trials WHERE state <> 'RUNNING'").fetchone()[0] > 0

        try:
            wait_for(told, "a finished trial", 240, every=0.5)
            pg.stop()
            paused["at"] = time.monotonic()
            time.sleep(5)
        except Exception as exc:  # noqa: BLE001 - said by the test's assertion
            paused["error"] = f"{type(exc).__name__}: {exc}"
        finally:
            try:
                pg.start()
            except Exception as exc:  # noqa: BLE001
                paused["error"] = f"PostgreSQL did not start again: {exc}: {pg.log_tail()}"

    fault = threading.Thread(target=pause_the_database_once_a_trial_is_told, daemon=True)
    fault.start()
    r = drive(["-m", "hydra/sweeper=search", *on_cluster(cluster, "restart"), f"search.storage={url}",
               "search.trials=4", "hydra.launcher.workers=2", "light.intensity=interval(0.2,1.0)", *SMALL], tmp_path,
              env={"GARAGE_EXP_STORAGE_WAIT": "120", "GARAGE_EXP_TRACKING_WAIT": "120"})
    fault.join(timeout=60)
    out = r.stdout + r.stderr
    assert "at" in paused and "error" not in paused, paused.get("error", "") + out[-3000:]
    assert r.returncode == 0, out[-4000:] + pg.log_tail()
    assert "Traceback" not in out, out[-4000:]
    assert "not answering; retrying for up to 120 s" in out and "answers again after" in out, out[-4000:]
    name = optuna.get_all_study_names(url)[0]
    study = optuna.load_study(study_name=name, storage=url)
    assert sorted(t.number for t in study.trials) == list(range(4))
    assert all(t.state in (TrialState.COMPLETE, TrialState.PRUNED) for t in study.trials), study.trials
    runs = [r for r in child_runs(cluster["uri"], "restart") if "search_trial" in r.data.tags]
    assert sorted(int(r.data.tags["search_trial"]) for r in runs) == list(range(4))
    assert {r.info.status for r in runs} == {"FINISHED"}
    assert {t.user_attrs["run_id"] for t in study.trials} == {r.info.run_id for r in runs}
    mlc = tracking.client(cluster["uri"])
    parent = tracking.read_parent(tmp_path / "sweep")
    assert "search/search_report.md" in [a.path for a in mlc.list_artifacts(parent, "search")]


def test_a_sweep_loses_a_node_and_every_job_finishes_once(cluster, tmp_path):
    """4 jobs in batches of 2 (`hydra.launcher.batch`: a Ray task each) on 2 one-CPU nodes; once a job runs on
    the second node, that node is killed (raylet and workers): its batch runs again, resumed, on the head; 4
    runs finish, each once, and the parent holds the report."""
    second = cluster["second"]
    killed = {}

    def kill_second_once_it_runs_a_job():
        def running_there():
            return [r for r in child_runs(cluster["uri"], "lost") if r.info.status == "RUNNING"
                    and int(r.data.tags.get("pid", 0)) in second.pids()]

        try:
            # asked once a second: the first job on a node runs for seconds (its renderer and detector start),
            # and every ask is a search on the MLflow server and a scan of /proc, on the cores the jobs run on
            killed["run"] = wait_for(running_there, "a job on the second node", 240, every=1.0)[0].info.run_id
            second.kill()
        except AssertionError as exc:
            killed["error"] = str(exc)

    fault = threading.Thread(target=kill_second_once_it_runs_a_job, daemon=True)
    fault.start()
    r = drive(["-m", *on_cluster(cluster, "lost"), "hydra.launcher.batch=2", *SMALL, "light=bright,dim",
               "palette.target_colours=[black],[white]"], tmp_path)
    fault.join(timeout=60)
    out = r.stdout + r.stderr
    assert "run" in killed, killed.get("error", "") + out[-3000:]
    assert r.returncode == 0, out[-4000:]
    assert "lost its Ray worker" in out and "running it again as resumed (retry 1 of 2)" in out, out[-4000:]
    done = re.search(r"4 jobs: (\d) finished, (\d) skipped", out)  # a job of the lost batch may have finished
    assert done and int(done[1]) + int(done[2]) == 4 and "0 failed" in out, out[-3000:]
    assert len(re.findall(r"job \d \(", out.split("lost its Ray worker")[0].splitlines()[-1])) == 2  # the batch
    runs = child_runs(cluster["uri"], "lost")
    assert sorted(r.info.status for r in runs) == ["FINISHED"] * 4, [(r.info.status, r.data.tags) for r in runs]
    assert len({r.data.tags["config_hash"] for r in runs}) == 4
    assert killed["run"] not in {r.info.run_id for r in runs}  # superseded by its resumed rerun, not counted
    mlc = tracking.client(cluster["uri"])
    parent = mlc.get_run(tracking.read_parent(tmp_path / "sweep"))
    assert parent.info.status == "FINISHED"
    assert "report/report.md" in [a.path for a in mlc.list_artifacts(parent.info.run_id, "report")]

    again = drive(["-m", *on_cluster(cluster, "lost"), *SMALL, "light=bright,dim",
                   "palette.target_colours=[black],[white]", "resume=true"], tmp_path)
    assert again.returncode == 0 and "4 jobs: 0 finished, 4 skipped (finished before)" in again.stdout, \
        (again.stdout + again.stderr)[-3000:]
    assert len(child_runs(cluster["uri"], "lost")) == 4
