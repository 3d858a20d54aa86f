"""The Hydra app and its MLflow runs, on plan-only jobs (dry_run=true: no rendering, no detection)."""

import mlflow
from conftest import run_app

from garage_exp.tracking import runs as tracking
from garage_exp.cli.app import quote_numeric_choices
from garage_exp.report import parse_overrides


def runs_of(uri: str, experiment: str = "garage_exp"):
    mlc = tracking.client(uri)
    exp = mlc.get_experiment_by_name(experiment)
    assert exp is not None, "experiment was not created"
    return mlc, mlc.search_runs([exp.experiment_id], max_results=100)


def test_quote_numeric_group_choices():
    assert quote_numeric_choices(["-m", "case=1,2,3", "light=dim", "seed=3", "+case=2", "case=light,3"]) == [
        "-m", "case='1','2','3'", "light=dim", "seed=3", "+case='2'", "case=light,'3'"]


def test_cfg_job_prints_composed_config(tmp_path):
    r = run_app(["--cfg", "job", "case=2", "light=dim"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert "site: bay_beside_pillar" in r.stdout and "name: dim" in r.stdout


def test_unknown_level_fails_with_hydra_message(tmp_path):
    r = run_app(["--cfg", "job", "light=dusk"], tmp_path)
    assert r.returncode != 0
    assert "Could not find 'light/dusk'" in r.stderr


def test_typo_in_field_fails(tmp_path):
    r = run_app(["--cfg", "job", "light.intensty=2"], tmp_path)
    assert r.returncode != 0
    assert "intensty" in r.stderr


def test_dry_run_logs_one_run_with_params_tags_and_artifacts(tmp_path, mlflow_uri):
    r = run_app(["dry_run=true", "plan=tiny", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr
    mlc, runs = runs_of(mlflow_uri)
    assert len(runs) == 1
    run = runs[0]
    assert run.info.status == "FINISHED"
    assert run.data.params["plan.name"] == "tiny"
    assert run.data.params["light.coverage"] == "1.0"
    assert run.data.tags["plan"] == "tiny"
    assert run.data.tags["git_commit"]
    assert run.data.tags["overrides"].split()[0] == "dry_run=true"
    arts = {a.path for a in mlc.list_artifacts(run.info.run_id)}
    assert {"config.yaml", "plan_map.png"} <= arts


def test_plan_file_from_anywhere(tmp_path, mlflow_uri):
    plan = tmp_path / "mine.yaml"  # the tiny plan's cells (a corner with its pillar: case 1's scene builds, as a
    plan.write_text("S: [[0, 0, 0, -1], [2, 1, 1, 0], [0, 0, 1, 0], [-1, 0, 3, -1]]\n"  # dry run's does too)
                    "R: [5.0, 6.0, 5.0, 5.0]\nC: [2.6, 2.6, 6.0, 2.6]\n")
    r = run_app(["dry_run=true", f"plan.file={plan}", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr
    _, runs = runs_of(mlflow_uri)
    assert runs[0].data.tags["plan"] == "mine"


def test_bad_plan_is_one_line_exit_2_and_no_run(tmp_path, mlflow_uri):
    plan = tmp_path / "bad.yaml"
    plan.write_text("S: [[2, 1, 7]]\nR: [6]\nC: [3, 3, 3]\n")
    r = run_app(["dry_run=true", f"plan.file={plan}", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "bad.yaml" in lines[0] and "row 0, column 2" in lines[0]
    assert "Traceback" not in r.stderr
    mlflow.set_tracking_uri(mlflow_uri)
    exp = mlflow.MlflowClient().get_experiment_by_name("garage_exp")
    assert exp is None or not mlflow.MlflowClient().search_runs([exp.experiment_id])


def test_multirun_has_parent_and_children(tmp_path, mlflow_uri):
    r = run_app(["-m", "dry_run=true", "plan=tiny", "light=bright,dim", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr
    _, runs = runs_of(mlflow_uri)
    parents = [x for x in runs if x.data.tags.get("sweep") == "parent"]
    children = [x for x in runs if x.data.tags.get("mlflow.parentRunId")]
    assert len(parents) == 1 and len(children) == 2
    assert {c.data.tags["mlflow.parentRunId"] for c in children} == {parents[0].info.run_id}
    assert sorted(c.data.params["light.name"] for c in children) == ["bright", "dim"]


def test_sweep_with_a_bad_job_is_refused_before_any_job_runs(tmp_path, mlflow_uri):
    # case.site=nonsense passes the schema (a string) but not the check of every job that runs before the
    # sweep opens its parent run. (A job that crashes after its start: tests/test_reliability_faults.py.)
    r = run_app(["-m", "plan=tiny", "case.site=nonsense,corner", "light=bright", f"tracking.uri={mlflow_uri}"],
                tmp_path, fresh_store=True)
    assert r.returncode == 2
    assert "case.site" in r.stderr and "nonsense" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "sweep").exists()


def test_parse_overrides():
    assert parse_overrides("light=dim case='1' +pillar=thick") == {"light": "dim", "case": "1", "pillar": "thick"}
