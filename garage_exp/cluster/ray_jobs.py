"""A sweep's jobs as Ray tasks (`hydra/launcher=ray`; the Hydra shell is hydra_plugins/garage_ray).

Each job is composed here, in the driver, and run in a Ray worker by Hydra's own `run_job`, so its dir, its
HydraConfig, its logging and its return value are what the local launcher gives. Ray keeps a worker process
for the next task of the same resources, and the renderer and detector worker a job starts stay in that process
(garage_exp.core.state), so a node's later jobs skip the shader compilation and the model loading.

A job whose node or worker process dies (not the job's own error: that is its return value, as locally) is
submitted again, on whatever node is left, as a resumed job (`resume=true`): a run it finished before it died is
counted, not rerun, and a run it left RUNNING is superseded (soft-deleted), so nothing counts twice. Once
`retries` are spent the job is left to `resume=true`: its run is closed as FAILED at the sweep's end.
"""

from __future__ import annotations

import copy
import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf, open_dict

from garage_exp.core.state import STATE

log = logging.getLogger("garage_exp")
GB = 1024**3


@dataclass
class RaySettings:
    """`hydra.launcher.*` (conf/hydra/launcher/ray.yaml)."""

    # null: the cluster this machine joined (`ray start`), else a local Ray started here; an address (auto,
    # HOST:PORT, ray://HOST:PORT) names a cluster that must answer
    address: str | None = None
    num_cpus: float = 1.0  # per job (per search worker)
    num_gpus: float = 0.0
    memory_gb: float | None = None  # Ray's scheduling reservation, not a limit
    retries: int = 2  # a job whose node or worker died is run again this many times
    workers: int = 2  # a search's trial loops at once, each a Ray task sharing the study's storage
    # a sweep's jobs per Ray task: a task (holding its num_gpus) runs its batch in one process, renderer and
    # detector warm, instead of each job queueing for the GPU on its own (a search batches with search.batch)
    batch: int = 1
    env: dict[str, str] = field(default_factory=dict)  # environment of the workers (Ray's runtime_env)

    def __post_init__(self) -> None:  # checked with the sweep's inputs, before anything is written
        from garage_exp.core.errors import GarageError

        if int(self.batch) < 1:
            raise GarageError(f"a batch of {self.batch} jobs: at least 1", "hydra.launcher.batch")

    def options(self) -> dict[str, Any]:
        out: dict[str, Any] = {"num_cpus": self.num_cpus, "num_gpus": self.num_gpus, "max_retries": 0}
        if self.memory_gb:
            out["memory"] = int(self.memory_gb * GB)
        return out


def settings(launcher_cfg) -> RaySettings:
    values = OmegaConf.to_container(launcher_cfg, resolve=True) if isinstance(launcher_cfg, DictConfig) \
        else dict(launcher_cfg)
    values = {k: v for k, v in values.items() if not k.startswith("_")}
    return RaySettings(**values)


def connect(conf: RaySettings) -> None:
    """Join the cluster (or start a local Ray) once per process; the workers inherit `env` and the tracking
    URI the driver uses (a job's run must land where its sweep's parent is). Called by the sweep's check, before
    anything is written: a named address that does not answer is a GarageError."""
    import ray

    if ray.is_initialized():
        return
    named = check_cluster(conf)
    if not named:
        joined = joined_cluster()
        if joined is None:
            print("garage_exp: no Ray cluster runs on this machine: starting a local Ray in this process (to use a "
                  "cluster: `ray start --head` first, or hydra.launcher.address=HOST:PORT)", flush=True)
        else:
            check_answers(joined, "the cluster this machine joined (`ray start`)")
    # workers' lines without colour codes (1 brings them back); for the command that started Ray
    STATE.setenv("RAY_COLOR_PREFIX", "0", "command", default=True)
    env = {str(k): str(v) for k, v in conf.env.items()}
    for name in ("MLFLOW_TRACKING_URI", "YOLO_OFFLINE", "GARAGE_EXP_TRACKING_WAIT", "GARAGE_EXP_STORAGE_WAIT"):
        if os.environ.get(name) and name not in env:
            env[name] = os.environ[name]
    ray.init(address=conf.address, runtime_env={"env_vars": env} if env else None, log_to_driver=True,
             logging_level=logging.WARNING, include_dashboard=False if named is None else None)


def check_cluster(conf: RaySettings) -> str | None:
    """A named cluster (hydra.launcher.address, else $RAY_ADDRESS) answers, unless this process already joined
    one: GarageError otherwise. Needs no job, so the sweep checks it before any model loads. Returns the name."""
    import ray

    named = conf.address or os.environ.get("RAY_ADDRESS") or None
    if named and not ray.is_initialized():
        check_answers(named, "hydra.launcher.address" if conf.address else "RAY_ADDRESS")
    return named


def disconnect() -> None:
    """At the sweep's end, before its summary: the driver leaves Ray (a local Ray it started stops), so no
    worker's late line prints after the summary; the jobs' logs are in their dirs."""
    import ray

    if ray.is_initialized():
        ray.shutdown()


def joined_cluster() -> str | None:
    """The address of the cluster `ray start` began on this machine (Ray's own lookup for address=None), or
    None when there is none and ray.init will start a local Ray."""
    from ray._private import services  # private, but the very rule ray.init(address=None) follows

    try:
        return services.canonicalize_bootstrap_address(None)
    except ConnectionError:
        return None


def check_answers(address: str, where: str) -> None:
    """GarageError in one line unless a Ray cluster answers at `address` (auto: the one this machine joined).
    ray.init itself would wait minutes on an address where nothing listens."""
    import socket

    from ray._private import services

    from garage_exp.core.errors import GarageError

    resolved = address
    if address == "auto":
        try:
            resolved = services.canonicalize_bootstrap_address_or_die("auto")
        except ConnectionError:
            resolved = None
    host, _, port = (resolved or "").removeprefix("ray://").rpartition(":")
    try:
        socket.create_connection((host, int(port)), timeout=3).close()
        return
    except (OSError, ValueError):
        pass
    raise GarageError(f"no Ray cluster answers at {address}: start one with `ray start --head` (on that host), or "
                      "leave hydra.launcher.address out (null) to start a local Ray in this process", where)


def lost(exc: BaseException) -> bool:
    """The task's node or worker process died (the job did not fail by itself)."""
    import ray.exceptions as rx

    if isinstance(exc, rx.RayTaskError):
        return False
    return isinstance(exc, (rx.WorkerCrashedError, rx.NodeDiedError, rx.LocalRayletDiedError, rx.ObjectLostError,
                            rx.OwnerDiedError, rx.RaySystemError, rx.ActorDiedError, rx.TaskUnschedulableError))


def _prepare_worker(singleton_state, cwd: str) -> None:
    from hydra.core.singleton import Singleton
    from hydra.core.utils import setup_globals

    setup_globals()
    Singleton.set_state(singleton_state)
    STATE.begin()  # this job's counts and outages; the process's warm renderer and detector stay
    if os.path.isdir(cwd):
        os.chdir(cwd)


def run_batch(hydra_context, task_function, cfgs: list[DictConfig], singleton_state, cwd: str) -> list:
    """In a Ray worker: a batch of jobs, each as Hydra's launchers run it, one after another in this process."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.core.utils import run_job

    returns = []
    for cfg in cfgs:
        _prepare_worker(singleton_state, cwd)
        HydraConfig.instance().set_config(cfg)
        returns.append(run_job(hydra_context=hydra_context, task_function=task_function, config=cfg,
                               job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir"))
    return returns


def job_config(hydra_context, config: DictConfig, overrides: list[str], idx: int) -> DictConfig:
    cfg = hydra_context.config_loader.load_sweep_config(config, list(overrides))
    with open_dict(cfg):
        cfg.hydra.job.id = f"ray_{idx}"
        cfg.hydra.job.num = idx
        cfg.hydra.sweep.dir = str(config.hydra.sweep.dir)  # ${now:} resolved once, by the driver
    return cfg


def as_resumed(cfg: DictConfig) -> DictConfig:
    cfg = copy.deepcopy(cfg)
    with open_dict(cfg):
        cfg.resume = True
    return cfg


def lost_return(cfg: DictConfig, exc: BaseException):
    """What a job lost for good returns: the sweep counts its run (closed FAILED at the end) as failed."""
    from hydra.core.utils import JobReturn, JobStatus

    error = f"its Ray node or worker died ({type(exc).__name__})"
    value = {"error": error} if OmegaConf.select(cfg, "search.trial") is not None else math.nan
    return JobReturn(overrides=list(cfg.hydra.overrides.task), cfg=cfg, status=JobStatus.COMPLETED,
                     _return_value=value, working_dir=os.getcwd(), task_name=cfg.hydra.job.name)


def launch(conf: RaySettings, hydra_context, task_function, config: DictConfig, job_overrides, initial_job_idx: int):
    """Run the sweep's jobs on the cluster, `conf.batch` jobs a Ray task; the JobReturns in the jobs' order."""
    import ray
    from hydra.core.singleton import Singleton
    from hydra.core.utils import configure_log, setup_globals

    setup_globals()
    configure_log(config.hydra.hydra_logging, config.hydra.verbose)
    Path(str(config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
    connect(conf)
    remote = ray.remote(run_batch).options(**conf.options())
    state, cwd = Singleton.get_state(), os.getcwd()
    pending: dict[Any, tuple[list[int], list[DictConfig], int]] = {}

    def submit(ks: list[int], cfgs: list[DictConfig], attempt: int) -> None:
        pending[remote.remote(hydra_context, task_function, cfgs, state, cwd)] = (ks, cfgs, attempt)

    cfgs = []
    for k, overrides in enumerate(job_overrides):
        idx = initial_job_idx + k
        log.info(f"\t#{idx} : {' '.join(overrides)}")
        cfgs.append(job_config(hydra_context, config, overrides, idx))
    size = int(conf.batch)
    for start in range(0, len(cfgs), size):
        submit(list(range(start, min(start + size, len(cfgs)))), cfgs[start:start + size], 0)
    results: list[Any] = [None] * len(job_overrides)
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        ks, batch, attempt = pending.pop(done[0])
        try:
            for k, returned in zip(ks, ray.get(done[0])):
                results[k] = returned
        except Exception as exc:  # noqa: BLE001 - sorted below: a lost node is retried, anything else raised
            if not lost(exc):
                raise getattr(exc, "cause", None) or exc
            # Which of the batch's jobs finished is not known here: all run again, resumed, so a finished run
            # is counted and not rendered again (resume=true), and one left RUNNING is superseded.
            names = "; ".join(f"job {c.hydra.job.num} ({' '.join(c.hydra.overrides.task)})" for c in batch)
            if attempt < conf.retries:
                print(f"garage_exp: {names} lost its Ray worker ({type(exc).__name__}); "
                      f"running it again as resumed (retry {attempt + 1} of {conf.retries})", flush=True)
                submit(ks, [as_resumed(c) for c in batch], attempt + 1)
            else:
                print(f"garage_exp: {names} lost its Ray worker {attempt + 1} times; left for resume=true",
                      flush=True)
                for k, cfg in zip(ks, batch):
                    results[k] = lost_return(cfg, exc)
    return results
