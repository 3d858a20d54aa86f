"""A search on a Ray cluster: `hydra.launcher.workers` trial loops, each a Ray task, sharing one Optuna study.

This is Optuna's own pattern for distributed optimisation (workers that share an RDB storage, each asking and
telling), with Ray placing the workers: no scheduler of ours. Each worker runs the same trial loop a local
search runs (garage_exp.search.loop), launching its trials in its own process, so its renderer and detector stay
warm across its trials. The driver waits for the workers, then analyses the study and logs the report on the
search's parent run, as a local search does. A worker whose node died is started again (it continues the
study; the trial it was running is failed by Optuna's heartbeat once stale).
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from garage_exp.cluster.ray_jobs import RaySettings, _prepare_worker, connect, lost


def worker(hydra_context, task_function, config: DictConfig, singleton_state, cwd: str) -> list[int]:
    """In a Ray worker: the trial loop until the study holds its trials; the trial numbers this worker ran."""
    from garage_exp.search import sweep
    from garage_exp.search.launch import CachedLaunch

    _prepare_worker(singleton_state, cwd)
    loader = hydra_context.config_loader
    launch = CachedLaunch(hydra_context, task_function, config, set(sweep.group_levels(loader)))
    return sweep.run(config, loader, launch)["ran"]


def run(conf: RaySettings, hydra_context, task_function, config: DictConfig) -> dict:
    """The study after `conf.workers` workers have filled it: what search.sweep.run returns."""
    import ray
    from hydra.core.singleton import Singleton

    from garage_exp.search import sweep

    Path(str(config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
    connect(conf)
    remote = ray.remote(worker).options(**conf.options())
    state, cwd = Singleton.get_state(), str(Path.cwd())
    pending = {remote.remote(hydra_context, task_function, config, state, cwd): 0 for _ in range(conf.workers)}
    ran: list[int] = []
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        attempt = pending.pop(done[0])
        try:
            ran.extend(ray.get(done[0]))
        except Exception as exc:  # noqa: BLE001 - a lost node's worker starts again; a worker's own error raises
            if not lost(exc):
                raise getattr(exc, "cause", None) or exc
            if attempt >= conf.retries:
                print(f"garage_exp: a search worker lost its Ray node {attempt + 1} times; not started again",
                      flush=True)
                continue
            print(f"garage_exp: a search worker lost its Ray node ({type(exc).__name__}); starting it again",
                  flush=True)
            pending[remote.remote(hydra_context, task_function, config, state, cwd)] = attempt + 1
    result = sweep.collect(config, hydra_context.config_loader, sorted(ran))
    return {**result, "who": f"its {conf.workers} Ray workers"}
