"""The MLflow run of one job: started with the config's params, logged through the client by run id, and kept
in a file while the tracking server is away (replayed by `resume=true`)."""

from __future__ import annotations

import contextlib
import json
import time
import traceback
from pathlib import Path
from typing import Any


from garage_exp.tracking.client import TrackingAway, client, retry
from garage_exp.tracking.experiments import experiment_id
from garage_exp.tracking.provenance import config_params, git_commit

PENDING_FILE = "tracking_pending.jsonl"
BATCH = 900  # metrics per log_batch request (MLflow's limit is 1000)


class JobRun:
    """The MLflow run of one job. Logging goes through the client (no global active run), so a sweep's
    parent run and the jobs of one process never interfere.

    With `pending` set (a file in the job's dir), a call the tracking server could not take (TrackingAway)
    is kept there instead of failing the job: the job finishes its frames and files, and resume=true logs
    the kept calls later (replay_pending) without rendering again. Each public call is one `_<name>` method
    that does it, so a kept call replays by its name."""

    def __init__(self, mlc, run_id: str, experiment_id: str | None = None, pending: Path | None = None):
        self.mlc, self.run_id, self.experiment_id, self.pending = mlc, run_id, experiment_id, pending
        self.kept = 0  # calls kept in the pending file
        self.ended = False  # end() was called (a job that met a full disk ends its run itself)

    def _call(self, op: str, *args) -> None:
        try:
            getattr(self, "_" + op)(*args)
        except TrackingAway:
            if self.pending is None:
                raise
            with open(self.pending, "a") as fh:
                fh.write(json.dumps([op, *args]) + "\n")
            self.kept += 1

    def log_metric(self, key: str, value: float, step: int = 0) -> None:
        self._call("log_metric", key, float(value), int(step))

    def _log_metric(self, key, value, step) -> None:
        retry(lambda: self.mlc.log_metric(self.run_id, key, value, step=step))

    def log_metrics(self, metrics: dict[str, float], step: int = 0) -> None:
        self._call("log_metrics", {k: float(v) for k, v in metrics.items()}, int(step))

    def _log_metrics(self, metrics, step) -> None:
        self._log_batch([(k, float(v), step) for k, v in metrics.items()])

    def log_series(self, key: str, values, steps=None) -> None:
        """A whole trajectory metric in few requests."""
        steps = range(len(values)) if steps is None else steps
        self._call("log_series", key, [float(v) for v in values], [int(s) for s in steps])

    def _log_series(self, key, values, steps) -> None:
        self._log_batch([(key, v, s) for s, v in zip(steps, values)])

    def _log_batch(self, points: list[tuple[str, float, int]]) -> None:
        """(key, value, step) points, stamped now, in requests of BATCH."""
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        batch = [Metric(key, value, now, step) for key, value, step in points]
        for k in range(0, len(batch), BATCH):
            retry(lambda part=batch[k:k + BATCH]: self.mlc.log_batch(self.run_id, metrics=part))

    def set_tag(self, key: str, value: Any) -> None:
        self._call("set_tag", key, str(value)[:5000])

    def _set_tag(self, key, value) -> None:
        retry(lambda: self.mlc.set_tag(self.run_id, key, value))

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        self._call("log_artifact", str(path), artifact_path)

    def _log_artifact(self, path, artifact_path) -> None:
        retry(lambda: self.mlc.log_artifact(self.run_id, path, artifact_path))

    def log_text(self, text: str, artifact_file: str) -> None:
        self._call("log_text", text, artifact_file)

    def _log_text(self, text, artifact_file) -> None:
        retry(lambda: self.mlc.log_text(self.run_id, text, artifact_file))

    def end(self, status: str = "FINISHED") -> None:
        self._call("end", status)
        self.ended = True

    def _end(self, status) -> None:
        retry(lambda: self.mlc.set_terminated(self.run_id, status))
        forget_artifact_repo(self.run_id)


class UnloggedRun(JobRun):
    """A search trial's stand-in run under `search.runs=per_search`: it takes a job's calls and logs nothing (no
    MLflow run is made: the search's parent run holds the trials' rows and the study's analysis, the study the
    trial's values and outcome). `run_id` is None."""

    def __init__(self):
        super().__init__(None, None)

    def _call(self, op: str, *args) -> None:
        if op == "end":
            self.ended = True


def forget_artifact_repo(run_id: str) -> None:
    """Drop MLflow's cached artifact repository of an ended run: MLflow keeps one (with its logging queue) for
    each of the last 1,024 runs that logged an artifact, about 20 kB each, which a long search's RSS carried
    (benchmarks/studies/soak.py). A later call for the run makes a new one."""
    try:
        from mlflow.tracking._tracking_service import utils
    except ImportError:  # MLflow moved it: nothing to forget
        return
    cache = getattr(utils, "_artifact_repos_cache", None)
    if isinstance(cache, dict):
        cache.pop(run_id, None)


@contextlib.contextmanager
def tracked_run(run: JobRun, *, traceback_file: bool = False):
    """The body of a command's run, and how the run ends: FINISHED when the body ends; on an exception, its
    error as the `error` tag (and the traceback as error.txt with `traceback_file`), then KILLED for Ctrl-C or
    SIGTERM (KeyboardInterrupt: the command's shell raises it for both) or FAILED for anything else, and the
    exception goes on. A run the body already ended (a full disk closes it its own way) is left as it is."""
    try:
        yield run
    except BaseException as exc:
        if not run.ended:
            try:
                run.set_tag("error", f"{type(exc).__name__}: {exc}".strip())
                if traceback_file:
                    run.log_text(traceback.format_exc(), "error.txt")
            finally:
                run.end("KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED")
        raise
    if not run.ended:
        run.end("FINISHED")


def start_job_run(cfg, run_name: str, tags: dict[str, str], parent_run_id: str | None) -> JobRun:
    """A new run of the job in the config's experiment, with the git commit, the given tags and the config's
    params (under a parent run when given)."""
    from mlflow.entities import Param
    from mlflow.utils.mlflow_tags import MLFLOW_PARENT_RUN_ID, MLFLOW_RUN_NAME

    mlc = client(cfg.tracking.uri)
    exp_id = experiment_id(mlc, cfg.tracking.experiment)
    all_tags = {MLFLOW_RUN_NAME: run_name, "git_commit": git_commit(), **tags}
    if parent_run_id:
        all_tags[MLFLOW_PARENT_RUN_ID] = parent_run_id
    run = retry(lambda: mlc.create_run(exp_id, run_name=run_name, tags=all_tags))
    job = JobRun(mlc, run.info.run_id, exp_id)
    params = [Param(k, v) for k, v in sorted(config_params(cfg).items())]
    try:
        for k in range(0, len(params), 100):
            retry(lambda part=params[k:k + 100]: mlc.log_batch(job.run_id, params=part))
    except BaseException as exc:  # Ctrl-C or SIGTERM before the job's body owns the run: it ends, not RUNNING
        job.end("KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED")
        raise
    return job


def replay_pending(cfg, run_id: str, pending: Path) -> None:
    """Log the calls a job kept while the server was away, in order, into its run (which ends FINISHED)."""
    run = JobRun(client(cfg.tracking.uri), run_id)
    for line in pending.read_text().splitlines():
        op, *args = json.loads(line)
        getattr(run, "_" + op)(*args)
    pending.rename(pending.with_name(PENDING_FILE + ".logged"))


def log_report(mlc, run_id: str, folder: str | Path, artifact_path: str = "report") -> None:
    """Log a report folder (report.md and its figures) with report.html written beside report.md: the page
    the MLflow UI's artifact preview shows with its figures (it shows neither a markdown file's images nor
    files an HTML page links to)."""
    from garage_exp.tracking.page import html_page

    if (Path(folder) / "report.md").is_file():
        html_page(Path(folder) / "report.md")
    retry(lambda: mlc.log_artifacts(run_id, str(folder), artifact_path))
