"""Hydra callbacks: check a sweep before it starts, its MLflow parent run, and its summary and report at the end."""

from __future__ import annotations

import contextlib
import logging
import os
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from garage_exp.tracking import runs as tracking
from garage_exp.core.state import STATE
from garage_exp.run.sweep_check import check_sweep, in_job, sweep_jobs  # noqa: F401 - the sweep's own check

log = logging.getLogger(__name__)
BASIC_LAUNCHER = "hydra._internal.core_plugins.basic_launcher.BasicLauncher"
def abandon_sweep(sweep: MlflowSweepCallback | None, exc: BaseException) -> None:
    """The sweep stopped without reaching its end (Ctrl-C, SIGTERM, a launcher crash): its parent run ends
    KILLED or FAILED with the reason, instead of RUNNING forever."""
    if sweep is None or not sweep.parent_run_id or sweep.ended:
        return
    if isinstance(exc, SystemExit) and not exc.code:
        return
    status = "KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED"
    try:
        mlc = tracking.client(sweep.uri)
        from garage_exp.core.exits import SweepStopped

        reason = f"sweep stopped: {exc}" if isinstance(exc, SweepStopped) else \
            f"sweep interrupted: {type(exc).__name__}: {exc}".strip()
        tracking.retry(lambda: mlc.set_tag(sweep.parent_run_id, "error", reason[:5000]))
        tracking.retry(lambda: mlc.set_terminated(sweep.parent_run_id, status))
        sweep.ended = True
    except tracking.TrackingAway:  # the parent stays open on the server; resume=true reopens it
        pass
    except Exception as err:  # never hide the original exception
        log.error("could not close the sweep's parent run: %s", err)


def _fatal(method):
    """Hydra turns an exception in a callback into a warning and goes on: a sweep whose check or parent run
    failed would run untracked, and one whose summary failed would exit 0. So a callback's error ends the
    process here: an input error as one line and exit 2, anything else with its traceback and exit 1."""
    import functools

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except Exception as exc:
            import sys
            import traceback

            from garage_exp.core.exits import EXIT_INPUT, input_error

            line = input_error(exc)
            if line is not None:
                print(f"garage_exp: {line}", file=sys.stderr)
                raise SystemExit(EXIT_INPUT) from None
            if isinstance(exc, tracking.TrackingAway):
                print(f"garage_exp: {exc}; rerun the same command with resume=true once the server is back",
                      file=sys.stderr)
                raise SystemExit(1) from None
            traceback.print_exc()
            print(f"garage_exp: sweep aborted: {method.__name__} failed: {type(exc).__name__}: {exc}",
                  file=sys.stderr)
            raise SystemExit(1) from None

    return wrapper


class MlflowSweepCallback(Callback):
    """Checks every job, then opens a parent run when a multirun starts; every job (in any process) reads its
    id from the sweep dir and becomes its child. A resumed sweep (resume=true, same overrides) reopens the
    parent of the interrupted one. At the end: a summary on stdout, the report logged on the parent."""

    def __init__(self) -> None:
        self.parent_run_id: str | None = None
        self.uri: str | None = None
        self.experiment_id: str | None = None
        self.jobs: int | None = None
        self.trials_summary: tuple[str, int] | None = None  # set by the search's sweeper under search.runs=per_search
        self.in_process = False
        self.failures = 0
        self.ended = False
        self.search = False

    @_fatal
    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        STATE.sweep = self  # the entry point reads the sweep's failures for its exit code
        from garage_exp.search import sweep as search_sweep

        self.search = search_sweep.is_search(config)
        cluster = None
        if uses_ray(config):  # the launcher's settings, and that a named cluster answers, need no job: checked
            # first, so that their refusal costs no model loading
            from garage_exp.cluster.ray_jobs import check_cluster, settings

            cluster = settings(config.hydra.launcher)
            check_cluster(cluster)
        study = None
        if self.search:  # the search's settings and space, before anything is written
            from hydra.core.global_hydra import GlobalHydra

            search_sweep.keep_on_cpus(config)  # before the checks start the detector's process
            search_sweep.check(config, GlobalHydra.instance().config_loader())
            study = search_sweep.study_name_of(config)
        jobs = check_sweep(config)  # before anything is written
        self.jobs = len(jobs) if jobs is not None else None
        if cluster is not None:  # the cluster is joined (or a local Ray starts) before anything is written
            from garage_exp.cluster.ray_jobs import connect

            connect(cluster)
        # Jobs in this very process (Hydra's basic launcher): a stopped sweep can count the finished ones.
        self.in_process = OmegaConf.select(config, "hydra.launcher._target_") == BASIC_LAUNCHER
        self.uri = config.tracking.uri
        mlc = tracking.client(self.uri)
        exp_id = self.experiment_id = tracking.experiment_id(mlc, config.tracking.experiment)
        task = list(config.hydra.overrides.task)
        overrides = " ".join(task)
        # A study has one parent run, whichever worker or resume comes to it: its key is the study's name.
        key = f"study:{study}" if study else tracking.sweep_key(task)
        tags = {"sweep": "parent", "overrides": overrides, "sweep_key": key, "git_commit": tracking.git_commit(),
                "sweep_dir": str(config.hydra.sweep.dir), "host": os.uname().nodename, "pid": str(os.getpid())}
        if self.jobs is not None:
            tags["jobs"] = str(self.jobs)
        with search_sweep.study_lock(config) if study else contextlib.nullcontext():
            self._open_parent(config, mlc, exp_id, key, tags, overrides, task, reuse=bool(study or config.get("resume")))

    def _open_parent(self, config, mlc, exp_id, key, tags, overrides, task, reuse: bool) -> None:
        from mlflow.utils.mlflow_tags import MLFLOW_RUN_NAME

        previous = tracking.find_parent(mlc, exp_id, key) if reuse else None
        if previous is not None:
            self.parent_run_id = previous.info.run_id
            tracking.retry(lambda: mlc.update_run(self.parent_run_id, status="RUNNING"))
            resumes = int(previous.data.tags.get("resumes", "0")) + 1
            for k, v in {**tags, "resumes": str(resumes)}.items():
                tracking.retry(lambda k=k, v=v: mlc.set_tag(self.parent_run_id, k, v))
            print(f"garage_exp: continuing sweep {self.parent_run_id} ({overrides})")
        else:
            name = f"{'search' if self.search else 'sweep'} {tracking.run_name(task)}".strip()
            tags[MLFLOW_RUN_NAME] = tracking.fit_name(name)
            run = tracking.retry(lambda: mlc.create_run(exp_id, tags=tags))
            self.parent_run_id = run.info.run_id
        tracking.write_parent(config.hydra.sweep.dir, self.parent_run_id)
        tracking.clear_resumed(config.hydra.sweep.dir)

    @_fatal
    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        if uses_ray(config):
            from garage_exp.cluster.ray_jobs import disconnect

            disconnect()
        if not self.parent_run_id:
            return
        from garage_exp.report import child_runs, summary, sweep_report

        mlc = tracking.client(self.uri)
        resumed = tracking.read_resumed(config.hydra.sweep.dir)
        close_dead_children(mlc, self.parent_run_id)
        report_path, report_error = None, None
        try:
            # A search's report is its study's analysis, which the sweeper logged on the parent itself.
            if not self.search:
                report_path = sweep_report(mlc, self.parent_run_id, config.hydra.sweep.dir, resumed=resumed)
        except Exception as exc:  # the sweep's runs are safe; a failed summary must not hide them
            log.error("sweep report failed: %s", exc)
            tracking.retry(lambda: mlc.set_tag(self.parent_run_id, "report_error", str(exc)[:5000]))
            report_error = exc
        if self.trials_summary is not None:  # a search without a run per trial: the study says how they ended
            text, self.failures = self.trials_summary
        else:
            runs = child_runs(mlc, self.parent_run_id, resumed)
            text, self.failures = summary(runs, self.jobs, search=self.search)
        report_line = [f"  report: {report_path}"] if report_path else []
        print("\n".join([text, *report_line, ui_hint(self.uri, self.experiment_id)]))
        status = "FAILED" if self.failures or report_error else "FINISHED"
        tracking.retry(lambda: mlc.set_tag(self.parent_run_id, "jobs_failed", str(self.failures)))
        tracking.retry(lambda: mlc.set_terminated(self.parent_run_id, status))
        self.ended = True


def uses_ray(config: DictConfig) -> bool:
    return str(OmegaConf.select(config, "hydra.launcher._target_") or "").endswith("garage_ray.launcher.RayLauncher")


def ui_hint(uri: str | None, experiment_id: str) -> str:
    """Where the sweep is in the MLflow UI, and how to serve a local store's UI."""
    serve = tracking.ui_command(uri)
    return f"  MLflow UI: {tracking.ui_link(uri, experiment_id)}" + (f" (after: {serve})" if serve else "")


def close_dead_children(mlc, parent_run_id: str) -> None:
    """At the end of a sweep every job has returned: a child still RUNNING lost its process (a worker killed
    by the OOM killer, a segfault) and ends FAILED, so that nothing looks alive that is not."""
    parent = tracking.retry(lambda: mlc.get_run(parent_run_id))
    runs = tracking.retry(lambda: mlc.search_runs(
        [parent.info.experiment_id],
        filter_string=f"tags.mlflow.parentRunId = '{parent_run_id}' and attributes.status = 'RUNNING'",
        max_results=10000))
    for r in runs:
        rid = r.info.run_id
        tracking.retry(lambda rid=rid: mlc.set_tag(rid, "error", "the job's process ended without closing its run"))
        tracking.retry(lambda rid=rid: mlc.set_terminated(rid, "FAILED"))
