"""The tracking package's parts (issue 32, items 5 and 7): the client and its retry across an absent server,
provenance (a job's identity, run names, params), a job's run and the sweep's files, each in its own module, the
`runs` module the layers above import, the store's path, and the UI's links as a command."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REFUSED

from garage_exp.core.paths import PROJECT_ROOT
from garage_exp.tracking import client, jobrun, provenance, runs, sweepfiles, ui


def test_the_runs_module_names_every_part_it_offers():
    for name in runs.__all__:
        assert hasattr(runs, name), name
    assert runs.retry is client.retry and runs.JobRun is jobrun.JobRun and runs.ui_link is ui.ui_link


class FakeClient:
    """log_batch records the metrics of each request; set_tag fails while `away`."""

    def __init__(self):
        self.batches, self.tags, self.away = [], {}, False

    def log_batch(self, run_id, metrics=()):
        self.batches.append([(m.key, m.value, m.step) for m in metrics])

    def set_tag(self, run_id, key, value):
        if self.away:
            raise client.TrackingAway("away")
        self.tags[key] = value


def test_a_series_goes_in_requests_of_900_and_metrics_alike():
    mlc = FakeClient()
    run = jobrun.JobRun(mlc, "r1")
    run.log_series("loss", [float(k) for k in range(2000)])
    assert [len(b) for b in mlc.batches] == [900, 900, 200]
    assert mlc.batches[1][0] == ("loss", 900.0, 900)
    run.log_metrics({"a": 1, "b": 2.5}, step=3)
    assert mlc.batches[-1] == [("a", 1.0, 3), ("b", 2.5, 3)]


def test_calls_the_server_missed_are_kept_and_replayed_in_order(tmp_path, monkeypatch):
    mlc = FakeClient()
    pending = tmp_path / jobrun.PENDING_FILE
    run = jobrun.JobRun(mlc, "r1", pending=pending)
    mlc.away = True
    run.set_tag("k", "v")
    run.log_metrics({"m": 2.0})
    assert run.kept == 1 and mlc.tags == {}  # the metrics got through, the tag was kept
    assert [json.loads(line) for line in pending.read_text().splitlines()] == [["set_tag", "k", "v"]]
    mlc.away = False
    monkeypatch.setattr(jobrun, "client", lambda uri: mlc)
    cfg = type("Cfg", (), {"tracking": type("T", (), {"uri": None})})()
    jobrun.replay_pending(cfg, "r1", pending)
    assert mlc.tags == {"k": "v"} and not pending.exists()
    assert (tmp_path / (jobrun.PENDING_FILE + ".logged")).is_file()


def test_sweep_files_keep_the_parent_and_the_resumed_runs(tmp_path):
    assert sweepfiles.read_parent(tmp_path / "s") is None
    sweepfiles.write_parent(tmp_path / "s", "p1")
    assert sweepfiles.read_parent(tmp_path / "s") == "p1"
    for rid in ("b", "a", "b"):
        sweepfiles.add_resumed(tmp_path / "s", rid)
    assert sweepfiles.read_resumed(tmp_path / "s") == ["a", "b"]
    sweepfiles.clear_resumed(tmp_path / "s")
    assert sweepfiles.read_resumed(tmp_path / "s") == []


def test_a_sweep_key_ignores_order_resume_and_the_store():
    key = provenance.sweep_key(["light=dim", "case=1"])
    assert key == provenance.sweep_key(["case=1", "resume=true", "light=dim", "tracking.uri=sqlite:///x.db"])
    assert key != provenance.sweep_key(["light=bright", "case=1"])
    assert provenance.flatten({"a": {"b": 1, "c": [1, 2]}, "d": [{"e": 3}]}) == {"a.b": "1", "a.c": "[1, 2]",
                                                                               "d.0.e": "3"}


def test_the_ui_links_are_a_command(tmp_path):
    """`make ui` prints the links with `python -m garage_exp.tracking.ui`."""
    uri = f"sqlite:///{tmp_path / 'x.db'}"
    r = subprocess.run([sys.executable, "-m", "garage_exp.tracking.ui", "--uri", uri], cwd=PROJECT_ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == f"garage_exp: no experiment in {uri} yet (make run, or python -m garage_exp ...)"


def test_make_ui_serves_the_store_it_is_given(tmp_path):
    """`make ui UI_STORE=URI` (issue 47, item 9: it was hard-wired to outputs/mlflow.db): the recipe, as make
    would run it, creates or checks that sqlite store, prints its links and serves it, on localhost only; without
    UI_STORE, the project's own store. The server itself is not started (tests/test_mlflow_ui.py serves one)."""
    import shlex

    def recipe(*variables: str) -> list[str]:
        out = subprocess.run(["make", "-n", "--no-print-directory", "ui", f"BIN={Path(sys.executable).parent}",
                              *variables], cwd=PROJECT_ROOT, capture_output=True, text=True, check=True).stdout
        return [ln for ln in out.splitlines() if "garage_exp.tracking" in ln or "mlflow ui" in ln]

    own = f"sqlite:///{PROJECT_ROOT / 'outputs' / 'mlflow.db'}"
    assert all(own in line for line in recipe())
    uri = f"sqlite:///{tmp_path / 'search' / 'mlflow.db'}"
    (tmp_path / "search").mkdir()
    *prepare, serve = recipe(f"UI_STORE={uri}")
    assert shlex.split(serve)[1:] == ["ui", "--backend-store-uri", uri, "--host", "127.0.0.1", "--port", "5000"]
    r = subprocess.run(["bash", "-ec", "\n".join(prepare)], cwd=PROJECT_ROOT, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "search" / "mlflow.db").is_file()  # created by the store command, under its lock
    assert r.stdout.strip() == f"garage_exp: no experiment in {uri} yet (make run, or python -m garage_exp ...)"
    assert runs.ui_command(uri) == f"make ui UI_STORE={uri}"  # what a sweep on that store tells the user to run


# -- the client: retry() across a server that went away (moved from test_world_faults.py) -----------------------------

def test_retry_waits_a_bounded_time_for_the_server_and_says_so_once(fresh_outage, monkeypatch, capsys):
    monkeypatch.setenv("GARAGE_EXP_TRACKING_WAIT", "60")
    calls = []

    def back_after_five():
        calls.append(1)
        if len(calls) <= 5:
            raise REFUSED
        return "ok"

    assert runs.retry(back_after_five) == "ok"
    assert fresh_outage == [1.0, 2.0, 4.0, 8.0, 16.0]  # exponential back-off
    err = capsys.readouterr().err.splitlines()
    assert err == ["garage_exp: tracking server http://127.0.0.1:1 not answering; retrying for up to 60 s "
                   "(GARAGE_EXP_TRACKING_WAIT)", "garage_exp: tracking server http://127.0.0.1:1 answers again after 31 s"]

    def never():
        raise REFUSED

    fresh_outage.clear()
    with pytest.raises(runs.TrackingAway, match="away for 60 s"):
        runs.retry(never)
    assert sum(fresh_outage) == pytest.approx(60, abs=0.1) and max(fresh_outage) <= 30
    fresh_outage.clear()
    with pytest.raises(runs.TrackingAway):  # given up: later calls do not wait again
        runs.retry(lambda: "never called")
    assert fresh_outage == []


def test_a_tag_two_workers_set_at_once_on_one_run_is_written_again_and_kept(tmp_path, monkeypatch):
    """Two workers of one search tag their parent run at their ends: MLflow's sqlite store looks the tag up, then
    inserts it, and when the other worker's insert lands in between, this one fails on the key (a two-worker
    search once ended with exit 1 so). The race is made here on a real store: the other worker's write lands
    between this one's look-up and its insert. retry() writes it again, which finds the row and updates it."""
    from sqlalchemy.orm import Session

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    mine, other = client.client(uri), client.client(uri)
    run_id = mine.create_run(mine.create_experiment("race")).info.run_id
    real_merge, raced = Session.merge, []

    def merge_then_the_other_worker(self, instance, *args, **kwargs):
        merged = real_merge(self, instance, *args, **kwargs)
        if not raced and getattr(instance, "key", None) == "search_mode":
            raced.append(1)
            other.set_tag(run_id, "search_mode", "search")  # commits first
        return merged

    monkeypatch.setattr(Session, "merge", merge_then_the_other_worker)
    with pytest.raises(Exception, match="UNIQUE constraint failed"):  # the race itself, unretried
        mine.set_tag(run_id, "search_mode", "search")
    raced.clear()
    other.delete_tag(run_id, "search_mode")
    runs.retry(lambda: mine.set_tag(run_id, "search_mode", "suite"))
    assert raced == [1] and mine.get_run(run_id).data.tags["search_mode"] == "suite"
    calls = []

    def always_taken():
        calls.append(1)
        raise RuntimeError("(sqlite3.IntegrityError) UNIQUE constraint failed: tags.key, tags.run_uuid")

    with pytest.raises(RuntimeError, match="UNIQUE"):  # a key that stays taken is a real conflict
        runs.retry(always_taken, base_delay=0.0)
    assert len(calls) == client.RACED_ATTEMPTS


def test_after_a_signal_retry_never_waits(fresh_outage):
    from garage_exp.core.state import STATE

    STATE.stopping = True
    calls = []

    def refused():
        calls.append(1)
        raise REFUSED

    with pytest.raises(runs.TrackingAway):
        runs.retry(refused)
    assert calls == [1] and fresh_outage == []  # one attempt, no sleep
    with pytest.raises(runs.TrackingAway):  # the server failed once: no attempt at all
        runs.retry(refused)
    assert calls == [1]


# Run in a fresh interpreter: a pytest worker that ran other tests first holds their threads and libraries, and
# there this test's SIGTERM twice killed the worker (xdist: "node down: Not properly terminated") in a clean
# clone's full run, though it passes alone; a process of its own fails as a test, never as the worker.
SIGNAL_SCOPE = r"""
import os
import signal

import pytest
from garage_exp.core.exits import Terminated
from garage_exp.core.shell import command_scope
from garage_exp.tracking import runs

def store_call(signals):
    for sig in signals:
        signal.raise_signal(sig)  # to this (main) thread, whose Python handler runs at once
        for _ in range(100):  # let the handler run here, inside the call
            pass
    done.append(True)
    return "written"

with command_scope():
    done = []
    with pytest.raises(Terminated):
        runs.retry(lambda: store_call([signal.SIGTERM]))
    assert done == [True], "the call ran to its end before the interrupt"
    done = []
    with pytest.raises(KeyboardInterrupt) as second:
        runs.retry(lambda: store_call([signal.SIGTERM, signal.SIGINT]))
    assert done == [] and not isinstance(second.value, Terminated), "the second one came at once"
    assert runs.retry(lambda: "after") == "after"  # nothing left held
    os.environ["MLFLOW_TRACKING_URI"] = "http://127.0.0.1:1"
    done = []
    with pytest.raises(Terminated):
        runs.retry(lambda: store_call([signal.SIGTERM]))
    assert done == [], "a server's request: cut where it was"
print("signals held as they should be")
"""


def test_a_signal_during_a_store_call_is_raised_when_the_call_returns(tmp_path):
    """SIGTERM (or Ctrl-C) that comes while a database store's session is open is held: the call completes (its
    write is whole, no lock left to a connection nobody commits), then the interrupt is raised; a second signal
    while one is held raises at once. A tracking server's request is not held (a signal may cut it)."""
    import os

    env = {**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}",
           "PYTHONPATH": os.pathsep.join([str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", SIGNAL_SCOPE], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, (done.returncode, done.stderr[-3000:])
    assert done.stdout.strip().endswith("signals held as they should be")


# -- provenance: a job's identity, its run's name and params ------------------------------------------------------------

def test_resume_identity_includes_the_plan_file_content(tmp_path):
    """The same config over an edited plan file is a different job: resume does not skip it."""
    from conftest import compose_cfg

    plan = tmp_path / "mine.yaml"
    plan.write_text("S: [[2, 1, 3], [0, 0, 0]]\nR: [6, 5]\nC: [3, 3, 3]\n")
    cfg = compose_cfg(f"plan.file={plan}", "dry_run=true")
    resumed = compose_cfg(f"plan.file={plan}", "dry_run=true", "resume=true", "tracking.uri=sqlite:///elsewhere.db")
    before = runs.config_hash(cfg, runs.file_digest(plan))
    assert runs.config_hash(resumed, runs.file_digest(plan)) == before  # resume/tracking: same job
    plan.write_text("S: [[2, 1, 3], [0, 0, 0]]\nR: [6, 5]\nC: [3, 3, 4]\n")
    assert runs.config_hash(cfg, runs.file_digest(plan)) != before
    assert runs.sweep_key(["light=a,b", "resume=true", "tracking.uri=x"]) == runs.sweep_key(["light=a,b"])
    assert runs.sweep_key(["light=a,b"]) != runs.sweep_key(["light=a,c"])


def test_a_run_name_says_what_ran_and_fits_the_database():
    """resume and tracking.* do not change what runs: not in the name (nor the sweep's key); a name longer than
    MLflow's column is cut with an ellipsis."""
    assert provenance.run_name(["light=dim", "resume=true", "tracking.uri=sqlite:///x.db", "+tracking.x=1",
                                "case=1"]) == "light=dim case=1"
    assert not provenance.describes_run("~tracking") and provenance.describes_run("+light.intensity=0.3")
    long = provenance.fit_name("x" * 300)
    assert len(long) == provenance.NAME_MAX and long.endswith("...")
    assert provenance.fit_name("short") == "short"


def test_params_are_the_config_flattened_without_hydra():
    from omegaconf import OmegaConf

    cfg = OmegaConf.create({"light": {"name": "dim", "colour": [1, 0.9]}, "hydra": {"run": {"dir": "x"}},
                            "case": {"actors": [{"kind": "vehicle"}]}, "seed": 3})
    assert provenance.config_params(cfg) == {"light.name": "dim", "light.colour": "[1, 0.9]",
                                             "case.actors.0.kind": "vehicle", "seed": "3"}


def test_the_store_is_the_config_then_the_environment_then_the_projects(tmp_path, monkeypatch):
    from garage_exp.tracking import store

    monkeypatch.setenv("MLFLOW_TRACKING_URI", "http://elsewhere:5000")
    assert client.tracking_uri("sqlite:///mine.db") == "sqlite:///mine.db"
    assert client.tracking_uri(None) == "http://elsewhere:5000"
    monkeypatch.delenv("MLFLOW_TRACKING_URI")
    monkeypatch.setattr(client, "OUTPUTS_DIR", tmp_path / "outputs")
    assert client.tracking_uri(None) == f"sqlite:///{tmp_path / 'outputs' / 'mlflow.db'}"
    assert store.sqlite_path(f"sqlite:///{tmp_path}/a.db?timeout=30") == tmp_path / "a.db"
    assert store.sqlite_path("postgresql://db/mlflow") is None


def test_the_wait_for_a_server_is_the_environments_seconds(monkeypatch):
    monkeypatch.setenv("GARAGE_EXP_TRACKING_WAIT", "12.5")
    assert client.tracking_wait() == 12.5
    monkeypatch.setenv("GARAGE_EXP_TRACKING_WAIT", "-3")
    assert client.tracking_wait() == 0.0
    monkeypatch.setenv("GARAGE_EXP_TRACKING_WAIT", "soon")
    assert client.tracking_wait() == 180.0



def test_a_tracked_run_ends_finished_killed_or_failed_with_its_error(tmp_path):
    """tracking.tracked_run, the one way gym, train, verify and the job end their run: FINISHED, KILLED on Ctrl-C or
    SIGTERM (KeyboardInterrupt, which the shell raises for both), FAILED with the error (and its traceback with
    traceback_file); a run the body ended itself is left as it ended it."""
    import shutil

    from conftest import store_template

    from garage_exp.core.exits import Terminated

    shutil.copy(store_template(), tmp_path / "m.db")
    mlc = runs.client(f"sqlite:///{tmp_path / 'm.db'}")
    exp = runs.experiment_id(mlc, "t")

    def run_through(exc: BaseException | None, **kw):
        run = jobrun.JobRun(mlc, mlc.create_run(exp).info.run_id, exp)
        try:
            with runs.tracked_run(run, **kw):
                if exc is not None:
                    raise exc
        except BaseException as raised:
            assert raised is exc  # the exception goes on to the shell
        return mlc.get_run(run.run_id)

    assert run_through(None).info.status == "FINISHED"
    killed = run_through(Terminated("signal 15 (SIGTERM)"))
    assert killed.info.status == "KILLED" and killed.data.tags["error"] == "Terminated: signal 15 (SIGTERM)"
    assert run_through(KeyboardInterrupt()).info.status == "KILLED"
    failed = run_through(ValueError("bad"), traceback_file=True)
    assert failed.info.status == "FAILED" and failed.data.tags["error"] == "ValueError: bad"
    text = Path(mlc.download_artifacts(failed.info.run_id, "error.txt", str(tmp_path))).read_text()
    assert text.startswith("Traceback") and "ValueError: bad" in text
    run = jobrun.JobRun(mlc, mlc.create_run(exp).info.run_id, exp)
    with pytest.raises(OSError):
        with runs.tracked_run(run):
            run.end("FAILED")  # as a full disk closes it, with its own reason
            raise OSError("No space left on device")
    assert mlc.get_run(run.run_id).info.status == "FAILED" and "error" not in mlc.get_run(run.run_id).data.tags
