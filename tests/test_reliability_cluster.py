"""From one laptop to a cluster without new code (issue 5): the shipped hydra/launcher configs compose, and
submitit's local executor (the SLURM launcher's twin) runs a sweep whose jobs, each in its own process, log
under one parent run."""

from __future__ import annotations

import os
import shutil

from conftest import ROOT, compose_cfg, run_app

from garage_exp.tracking import runs as tracking


def hydra_config(*overrides: str):
    return compose_cfg(*overrides, hydra=True).hydra


def test_slurm_launcher_config_composes():
    launcher = hydra_config("hydra/launcher=slurm").launcher
    assert launcher._target_.endswith("submitit_launcher.SlurmLauncher")
    assert launcher.timeout_min == 240 and launcher.cpus_per_task == 4 and launcher.array_parallelism == 32
    assert "export YOLO_OFFLINE=1" in launcher.setup
    assert hydra_config("hydra/launcher=slurm", "hydra.launcher.partition=cpu").launcher.partition == "cpu"


def test_ray_launcher_config_composes():
    """`hydra/launcher=ray` is our plugin on Ray's current API (tests/test_cluster.py runs it on a cluster)."""
    launcher = hydra_config("hydra/launcher=ray", "hydra.launcher.num_cpus=4", "hydra.launcher.memory_gb=8").launcher
    assert launcher._target_ == "hydra_plugins.garage_ray.launcher.RayLauncher"
    from garage_exp.cluster.ray_jobs import GB, settings

    conf = settings(launcher)
    assert conf.address is None and conf.retries == 2 and conf.workers == 2
    assert conf.options() == {"num_cpus": 4, "num_gpus": 0, "max_retries": 0, "memory": 8 * GB}


def test_without_a_cluster_the_ray_launcher_starts_a_local_ray_and_says_so(monkeypatch, capsys):
    """Issue 31, item 8: no address given and no `ray start` cluster: one line, then a local Ray (not Ray's
    "Could not find any running Ray instance" traceback); the workers' lines come without colour codes."""
    import ray

    from garage_exp.cluster import ray_jobs

    calls = []
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.delenv("RAY_COLOR_PREFIX", raising=False)
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", lambda **kw: calls.append(kw))
    monkeypatch.setattr(ray_jobs, "joined_cluster", lambda: None)
    ray_jobs.connect(ray_jobs.settings(hydra_config("hydra/launcher=ray").launcher))
    assert [c["address"] for c in calls] == [None] and os.environ["RAY_COLOR_PREFIX"] == "0"
    assert capsys.readouterr().out.startswith("garage_exp: no Ray cluster runs on this machine: starting a local Ray")


def test_submitit_local_sweep_runs_each_job_in_its_own_process(tmp_path, mlflow_uri):
    r = run_app(["-m", "hydra/launcher=local", "dry_run=true", "plan=tiny", "light=bright,dim",
                 f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    mlc = tracking.client(mlflow_uri)
    runs = mlc.search_runs([mlc.get_experiment_by_name("garage_exp").experiment_id])
    parent = [x for x in runs if x.data.tags.get("sweep") == "parent"]
    jobs = [x for x in runs if x.data.tags.get("mlflow.parentRunId")]
    assert len(parent) == 1 and len(jobs) == 2 and len(runs) == 3
    assert all(j.info.status == "FINISHED" for j in jobs) and parent[0].info.status == "FINISHED"
    assert {j.data.tags["mlflow.parentRunId"] for j in jobs} == {parent[0].info.run_id}
    pids = {j.data.tags["pid"] for j in jobs}
    assert len(pids) == 2 and parent[0].data.tags["pid"] not in pids  # one process per job, as on SLURM
    assert (tmp_path / "sweep" / ".submitit").is_dir()
    assert "sweep summary: 2 jobs: 2 finished" in r.stdout
    shutil.rmtree(tmp_path / "sweep" / ".submitit", ignore_errors=True)
