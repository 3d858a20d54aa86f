"""The tracking package's parts (issue 32, item 5): the client, provenance, a job's run and the sweep's files,
each in its own module, the `runs` module the layers above import, and the UI's links as a command."""

from __future__ import annotations

import json
import subprocess
import sys

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
