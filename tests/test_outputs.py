"""Where jobs write: with no tracking.uri and no $MLFLOW_TRACKING_URI the store is outputs/mlflow.db, and a
job writes nothing outside outputs/ (not in the working dir, not in the checkout). Run on a copy of the
project so that the real checkout's outputs/ is left alone; plan-only jobs."""

from __future__ import annotations

import os
import shutil
import subprocess

from conftest import PYTHON, ROOT

from garage_exp.tracking import runs as tracking


def snapshot(root):
    return {p.relative_to(root) for p in root.rglob("*") if "__pycache__" not in p.parts}


def test_default_store_is_outputs_mlflow_db_and_jobs_write_only_under_outputs(tmp_path):
    project = tmp_path / "project"
    for part in ("garage_exp", "conf", "plans"):
        shutil.copytree(ROOT / part, project / part, ignore=shutil.ignore_patterns("__pycache__"))
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    before = snapshot(project)
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    env["PYTHONPATH"] = str(project)
    # the copy has no ../shared beside it, and a dry run builds the scene (its vehicles included)
    env["GARAGE_EXP_ASSETS"] = str(ROOT.parent / "shared" / "assets")
    r = subprocess.run([PYTHON, "-m", "garage_exp", "dry_run=true", "plan=tiny"], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    new = snapshot(project) - before
    assert new and all(p.parts[0] == "outputs" for p in new), sorted(str(p) for p in new if p.parts[0] != "outputs")
    assert list(cwd.iterdir()) == []  # nothing in the working dir
    store = project / "outputs" / "mlflow.db"
    assert store.is_file()
    mlc = tracking.client(f"sqlite:///{store}")
    runs = mlc.search_runs([mlc.get_experiment_by_name("garage_exp").experiment_id])
    assert len(runs) == 1 and runs[0].info.status == "FINISHED"
    assert {p.parts[1] for p in new if len(p.parts) > 1} >= {"mlflow.db", "runs"}
    # A sweep's dir is under outputs/ too (conf/config.yaml): ${garage_root:}/outputs/multirun/...
    assert "${garage_root:}/outputs/multirun/" in (project / "conf" / "config.yaml").read_text()
