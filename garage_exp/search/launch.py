"""Trials launched in the sweeper's process, with one config composition per combination of group levels.

Hydra's basic launcher composes every job's config from the files (about 0.6 s here, a fifth of a 5-frame
trial). A trial differs from the next by a few values, so this launcher composes once per combination of
group levels (and structural overrides), then sets the trial's values on a copy (search/compose.py).
Everything else is Hydra's basic launcher: `run_job`, the job's dir, HydraConfig, logging. A one-shot search's
trials (`search.runs=per_search`) skip `run_job`'s two copies of the config, HydraConfig's copy of Hydra's node
(`hand_hydra_node`) and the per-job log file (`run_lean`).
A search whose space has requirements composes each draw to check it (search/loop.py `rejects`); the launch of
that draw takes that very composition (`last`) instead of composing it again (a copy of the cached config and
its ~50 values set: about 0.05 s a scenario on the wide space when the copy was deepcopy's, ~6 ms now), and sets
Hydra's node as the job's then (`Compositions.as_job`): the check reads none of it.

A batch's jobs are numbered by Hydra's `initial_job_idx` (consecutive), or by the list of their numbers: a search
batch's trial numbers, with gaps where the pre-screen pruned a trial (the job's dir is its trial's number).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobReturn, JobRuntime, configure_log, run_job, setup_globals
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from garage_exp.search.compose import Compositions
from garage_exp.search.plain_draw import PlainDraws

log = logging.getLogger(__name__)


class CachedLaunch:
    def __init__(self, hydra_context, task_function, config: DictConfig, groups: set[str]):
        self.hydra_context, self.task_function, self.config, self.groups = hydra_context, task_function, config, groups
        self.compositions = Compositions(hydra_context.config_loader, config, groups)
        # A draw's first look from plain data, before any composition (search/plain_draw.py, search/loop.py)
        self.plain = PlainDraws(self.compositions)
        # The last composition and its overrides, taken once by the launch of the same overrides. Who composes
        # may change it only as the job's own preflight does (run/preflight.hand_on: the plan's garage keys).
        self.last: tuple[tuple[str, ...], DictConfig] | None = None

    def compose(self, overrides: list[str]) -> DictConfig:
        """A draw's config for the search's check: composed once per combination of group levels, its values set
        on a copy, Hydra's node left as composed (Compositions.compose job=False) until a launch takes it."""
        cfg = self.compositions.compose(overrides, job=False)
        self.last = (tuple(overrides), cfg)
        return cfg

    def take(self, overrides: list[str]) -> DictConfig:
        """The job's config: the last composition when it was of these overrides (once), made a job's, else
        composed."""
        last, self.last = self.last, None
        if last is not None and last[0] == tuple(overrides):
            return self.compositions.as_job(last[1], list(overrides))
        return self.compositions.compose(list(overrides))

    def __call__(self, batch, initial_job_idx: int | Sequence[int]):
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        Path(str(self.config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
        runs = []
        for idx, overrides in zip(job_numbers(initial_job_idx, len(batch)), batch):
            log.info(f"\t#{idx} : {' '.join(overrides)}")
            cfg = self.take(list(overrides))
            with open_dict(cfg):
                cfg.hydra.job.id = idx
                cfg.hydra.job.num = idx
                cfg.hydra.output_subdir = None  # the job writes its own config.yaml; .hydra/ cost 0.07 s a trial
            if OmegaConf.select(cfg, "search.runs") == "per_search":
                runs.append(self.run_lean(cfg))
            else:
                runs.append(run_job(hydra_context=self.hydra_context, task_function=self.task_function, config=cfg,
                                    job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir"))
            configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        return runs

    def run_lean(self, cfg: DictConfig) -> JobReturn:
        """Hydra's `run_job` for a one-shot trial (`search.runs=per_search`), without its two copies of the
        config: the composition is this trial's own copy already (`compose`), so the job is handed it with its
        `hydra` node taken out (as Hydra hands a job its config) after HydraConfig took its copy of that node.
        No per-job log file is set up (the trial has no run to log it on). The job's dir, HydraConfig, the
        callbacks and the JobReturn are Hydra's."""
        from hydra.core.utils import JobStatus, _flush_loggers, env_override

        previous = HydraConfig.instance().cfg
        out = os.path.abspath(os.path.join(str(cfg.hydra.sweep.dir), str(cfg.hydra.sweep.subdir)))
        with read_write(cfg.hydra.runtime), open_dict(cfg.hydra.runtime):
            cfg.hydra.runtime.output_dir = out
        hand_hydra_node(cfg)
        try:
            Path(out).mkdir(parents=True, exist_ok=True)
            ret = JobReturn(overrides=list(cfg.hydra.overrides.task), hydra_cfg=HydraConfig.instance().cfg,
                            working_dir=os.getcwd())
            env = dict(cfg.hydra.job.env_set)
            self.hydra_context.callbacks.on_job_start(config=cfg, task_function=self.task_function)
            with read_write(cfg), open_dict(cfg):
                del cfg["hydra"]  # HydraConfig holds the node now
            ret.cfg = cfg
            with env_override(env):
                try:
                    ret.return_value = self.task_function(cfg)
                    ret.status = JobStatus.COMPLETED
                except Exception as exc:  # as Hydra's run_job: the JobReturn raises it when read
                    ret.return_value = exc
                    ret.status = JobStatus.FAILED
            ret.task_name = JobRuntime.instance().get("name")
            _flush_loggers()
            self.hydra_context.callbacks.on_job_end(config=ret.hydra_cfg, job_return=ret)
            return ret
        finally:
            HydraConfig.instance().cfg = previous


def hand_hydra_node(cfg: DictConfig) -> None:
    """`HydraConfig.instance().set_config(cfg)` without its copy of the `hydra` node: the node itself is handed
    over, read-only, under a container of its own whose parent is `cfg`, as Hydra's copy is (so that it may
    interpolate the job's keys). `run_lean` takes the node out of the job's config next, so nothing else holds
    it; Hydra's copy of it (a fifth of a composed config) was ~14 ms of a one-shot trial, the largest single
    step of its launch."""
    from hydra.conf import HydraConf
    from omegaconf import flag_override

    hydra = cfg._get_node("hydra")
    OmegaConf.set_readonly(hydra, True)
    node_type = OmegaConf.get_type(cfg, "hydra")
    assert node_type is not None and issubclass(node_type, HydraConf)
    held = OmegaConf.create({})
    with flag_override(held, "no_deepcopy_set_nodes", True):
        held["hydra"] = hydra
    held.hydra._set_parent(cfg)
    HydraConfig.instance().cfg = held


def job_numbers(first: int | Sequence[int], n: int) -> list[int]:
    """The numbers of a batch of `n` jobs: consecutive from `first`, or `first` itself when it lists them."""
    if isinstance(first, int):
        return list(range(first, first + n))
    numbers = [int(k) for k in first]
    if len(numbers) != n:
        raise ValueError(f"{len(numbers)} job numbers for a batch of {n}")
    return numbers


def launch_in_runs(launcher, batch, first: int | Sequence[int]) -> list:
    """A batch through a Hydra launcher, whose API numbers a batch from one index: one launch per run of
    consecutive numbers (a batch without gaps is one launch), the returns in the batch's order."""
    numbers = job_numbers(first, len(batch))
    returns: list = []
    start = 0
    for k in range(1, len(batch) + 1):
        if k == len(batch) or numbers[k] != numbers[k - 1] + 1:
            returns.extend(launcher.launch(batch[start:k], initial_job_idx=numbers[start]))
            start = k
    return returns
