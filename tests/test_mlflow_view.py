"""What the MLflow UI is given to show: params and run names that say what ran, the experiment's kind and saved
view, the links the sweep and `make ui` print, and the report as a self-contained HTML page. The browser's view
of all this is tests/test_mlflow_ui.py."""

from __future__ import annotations

import base64
import json
import re

import pytest
from conftest import run_app

from garage_exp.tracking import runs as tracking
from garage_exp.tracking.page import html_page

PNG = base64.b64decode("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR4nGNgYGD4DwABBAEAHnOcQAAAAABJRU5Er"
                       "kJggg==")  # 1 x 1 pixel


@pytest.fixture(scope="module")
def dry_job(tmp_path_factory):
    """A plan-only job on a user's plan file, with a user's light level that has no `name:`, and a name given
    on the command line to another group."""
    tmp = tmp_path_factory.mktemp("dry")
    uri = f"sqlite:///{tmp / 'mlflow.db'}"
    plan = tmp / "big.yaml"
    plan.write_text("S: [[0, 0, 0, -1], [2, 1, 1, 0], [0, 0, 1, 0], [-1, 0, 3, -1]]\n"  # the tiny plan's cells: case
                    "R: [5.0, 6.0, 5.0, 5.0]\nC: [2.6, 2.6, 6.0, 2.6]\n")  # 1's scene builds (a dry run builds it)
    (tmp / "conf" / "light").mkdir(parents=True)
    (tmp / "conf" / "light" / "night.yaml").write_text("coverage: 0.1\nintensity: 0.5\nambient: 0.005\n")
    args = ["--config-dir", str(tmp / "conf"), "dry_run=true", f"plan.file={plan}", "light=night", "occluder=none",
            "occluder.name=no_pillar", f"tracking.uri={uri}"]
    r = run_app(args, tmp)
    assert r.returncode == 0, r.stderr
    mlc = tracking.client(uri)
    exp = mlc.get_experiment_by_name("garage_exp")
    (run,) = mlc.search_runs([exp.experiment_id])
    return tmp, r, mlc, exp, run, args


def test_params_and_run_name_name_the_plan_file_and_the_level_that_ran(dry_job):
    """plan.file=big.yaml used to log plan.name=research (the default group's name); a user's light level
    without `name:` logged light.name=bright (the schema's default)."""
    tmp, r, mlc, exp, run, args = dry_job
    assert run.data.params["plan.name"] == run.data.tags["plan"] == "big"
    assert run.data.params["light.name"] == "night" and run.data.params["light.coverage"] == "0.1"
    assert run.data.params["case.name"] == "1" and run.data.params["sensor.name"] == "camera"  # look=real's
    assert run.data.params["occluder.name"] == "no_pillar"  # a name given on the command line is kept
    assert run.data.tags["mlflow.runName"] == " ".join(args[2:-1])  # where it is logged is not part of it
    config = open(mlc.download_artifacts(run.info.run_id, "config.yaml", str(tmp))).read()
    assert "name: big" in config and "name: night" in config
    # the job's own line points at the run in the UI
    assert f"MLflow UI: {tracking.ui_link(args[-1].split('=', 1)[1], exp.experiment_id, run.info.run_id)}" in r.stdout


def test_the_experiment_is_a_model_experiment_with_the_saved_view(dry_job):
    exp = dry_job[3]
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    envelope = json.loads(exp.tags[f"mlflow.sharedViewState.{tracking.VIEW_KEY}"])
    assert isinstance(envelope["name"], str) and isinstance(envelope["createdAt"], int)
    state = json.loads(envelope["state"])  # the UI's envelope holds its state as a JSON string
    assert "params.`light.name`" in state["selectedColumns"] and "metrics.`confidence_mean`" in state["selectedColumns"]
    assert set(state["columnWidths"]) <= set(state["columnOrder"])  # the UI sizes only ordered columns


def test_older_experiments_get_kind_and_view_once_and_make_ui_lists_them(tmp_path):
    uri = f"sqlite:///{tmp_path / 'x.db'}"
    mlc = tracking.client(uri)
    assert "no experiment" in tracking.links(uri)
    old = mlc.create_experiment("old")  # as an older version made it
    other = mlc.create_experiment("other")  # not ours: no saved view, so its link cannot ask for one
    assert tracking.experiment_id(mlc, "old") == old
    assert mlc.get_experiment(old).tags["mlflow.experimentKind"] == "custom_model_development"
    mlc.set_experiment_tag(old, "mlflow.experimentKind", "genai_development")  # the user's own choice in the UI
    tracking.experiment_id(mlc, "old")
    assert mlc.get_experiment(old).tags["mlflow.experimentKind"] == "genai_development"
    assert tracking.links(uri).splitlines()[1:] == [f"  old: {tracking.ui_link(uri, old)}",
                                                    f"  other: {tracking.ui_link(uri, other, view=False)}"]


def test_links_open_the_runs_view_on_the_right_server(tmp_path, monkeypatch):
    local = f"sqlite:///{tmp_path / 'x.db'}"
    assert tracking.ui_link(local, "7") == ("http://127.0.0.1:5000/#/experiments/7/runs?workflowType=machine_learning"
                                            "&viewStateShareKey=factors")
    assert tracking.ui_link("http://mlflow.internal:5000/", "7", "abc") == (
        "http://mlflow.internal:5000/#/experiments/7/runs/abc?workflowType=machine_learning")
    assert tracking.ui_command(local) == f"make ui UI_STORE={local}"
    assert tracking.ui_command("https://mlflow.internal") is None
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)  # tracking.client() exports it, in-process
    assert tracking.ui_command(None) == "make ui"  # the project's own store


def test_run_names_leave_out_where_runs_are_logged():
    assert tracking.run_name(["light=dim", "tracking.uri=sqlite:///x.db", "resume=true", "+case=2"]) == \
        "light=dim +case=2"
    assert tracking.run_name(["tracking.experiment=x"]) == ""


def test_a_long_run_name_fits_the_database_column():
    """PostgreSQL refuses a run name over 250 characters (sqlite does not check): found on a search's parent."""
    name = tracking.run_name([f"case.actors.target.distance=interval(3.0,8.0{k})" for k in range(20)])
    assert len(name) == tracking.NAME_MAX and name.endswith("...") and name.startswith("case.actors.target")


def test_report_page_inlines_its_figures_and_nothing_else(tmp_path):
    (tmp_path / "heatmap.png").write_bytes(PNG)
    (tmp_path.parent / "outside.png").write_bytes(PNG)
    md = tmp_path / "report.md"
    md.write_text("# Sweep report\n\n| factor | level |\n|---|---|\n| light | <b>dim</b> |\n\n"
                  "![heat map](heatmap.png)\n\n![escape](../outside.png)\n\n![web](https://example.org/x.png)\n")
    page = html_page(md).read_text()
    assert page.startswith("<!doctype html>") and "<title>Sweep report</title>" in page
    assert "<td>light</td>" in page and "&lt;b&gt;dim&lt;/b&gt;" in page  # a table; text's HTML escaped
    srcs = re.findall(r'<img src="([^"]+)" alt="([^"]*)"', page)
    assert srcs[0] == (f"data:image/png;base64,{base64.b64encode(PNG).decode()}", "heat map")
    assert srcs[1:] == [("../outside.png", "escape"), ("https://example.org/x.png", "web")]
