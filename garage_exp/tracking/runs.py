"""MLflow: one run per job, a parent run per sweep, FAILED runs that keep their error."""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from garage_exp.core.state import STATE
from garage_exp.core.paths import OUTPUTS_DIR, PROJECT_ROOT

PARENT_FILE = "mlflow_parent_run_id"


def tracking_uri(uri: str | None = None) -> str:
    """Config override, then $MLFLOW_TRACKING_URI, then the project's sqlite store (absolute, cwd-proof)."""
    if uri:
        return uri
    if os.environ.get("MLFLOW_TRACKING_URI"):
        return os.environ["MLFLOW_TRACKING_URI"]
    OUTPUTS_DIR.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{OUTPUTS_DIR / 'mlflow.db'}"


def client(uri: str | None = None):
    import mlflow  # imported lazily: it costs ~1 s and plan-only commands do not need it

    from garage_exp.tracking.store import open_store

    uri = tracking_uri(uri)
    if uri.startswith(("http://", "https://")):
        # MLflow's own HTTP retries (7, with back-off up to two minutes each, and a 120 s timeout) sat more than
        # 15 minutes on a stopped server; retry() below waits instead, for a bounded time, and says so.
        os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")
        os.environ.setdefault("MLFLOW_HTTP_REQUEST_TIMEOUT", "30")
    mlflow.set_tracking_uri(uri)
    # The client opens (and may create) the store: a write, made once under the store's lock.
    return open_store(uri, lambda: retry(mlflow.MlflowClient))


# sqlite answers "database is locked" (or "database table is locked") when another process holds the write
# lock longer than its busy timeout; the write did not happen and is safe to repeat.
TRANSIENT = ("database is locked", "database table is locked")


# A tracking server that does not answer: refused or reset connections, timeouts, a proxy's 502-504; or a
# server whose PostgreSQL store restarts (it answers 503, or 500 with the driver's text, until the database is
# back).
UNREACHABLE = ("max retries exceeded", "connection refused", "connection aborted", "connection reset",
               "read timed out", "connecttimeout", "remotedisconnected", "failed to establish a new connection",
               "error code 429", "error code 502", "error code 503", "error code 504",
               "server closed the connection unexpectedly", "terminating connection due to administrator command",
               "the database system is shutting down", "the database system is starting up",
               "the database system is in recovery mode", "could not connect to server", "connection to server at")


class TrackingAway(Exception):
    """The tracking server stayed away longer than the wait allowed (or a signal came while it was away)."""


def tracking_wait() -> float:
    """How long a call waits for a tracking server that went away ($GARAGE_EXP_TRACKING_WAIT, seconds)."""
    from garage_exp.core.exits import wait_seconds

    return wait_seconds("GARAGE_EXP_TRACKING_WAIT")


def _unreachable(exc: BaseException) -> bool:
    text = f"{type(exc).__name__}: {exc}".lower()
    return any(t in text for t in UNREACHABLE)


def retry(fn, attempts: int = 10, base_delay: float = 0.1, max_delay: float = 5.0):
    """Call fn(), retrying on sqlite's 'database is locked' (several workers share one sqlite store) with
    jittered exponential back-off (~30 s in all before the error is raised), and on a tracking server that
    does not answer for up to tracking_wait() seconds (one line when the wait starts, one when the server is
    back), then TrackingAway. After Ctrl-C or SIGTERM nothing waits: one attempt, and none at all when the
    server was already away."""
    import random

    from garage_exp.core.exits import stopping

    k = 0
    while True:
        if STATE.tracking_given_up or (stopping() and STATE.tracking_down_since is not None):
            raise TrackingAway(f"tracking server {_uri()} away")
        try:
            result = fn()
        except Exception as exc:  # MlflowException wraps sqlalchemy's OperationalError and requests' errors
            if _unreachable(exc):
                now = time.monotonic()
                if STATE.tracking_down_since is None:
                    STATE.tracking_down_since = now
                    if not stopping():
                        print(f"garage_exp: tracking server {_uri()} not answering; retrying for up to "
                              f"{tracking_wait():.0f} s (GARAGE_EXP_TRACKING_WAIT)", file=sys.stderr, flush=True)
                waited = now - STATE.tracking_down_since
                if stopping() or waited >= tracking_wait():
                    STATE.tracking_given_up = not stopping()
                    raise TrackingAway(f"tracking server {_uri()} away for {waited:.0f} s") from None
                time.sleep(min(30.0, 2.0 ** min(k, 5), tracking_wait() - waited + 0.01))
                k += 1
                continue
            text = str(exc).lower()
            if not any(t in text for t in TRANSIENT) or k >= attempts - 1:
                raise
            time.sleep(min(max_delay, base_delay * (2**k)) * (0.5 + random.random()))
            k += 1
            continue
        if STATE.tracking_down_since is not None:
            print(f"garage_exp: tracking server {_uri()} answers again after {time.monotonic() - STATE.tracking_down_since:.0f} s",
                  file=sys.stderr, flush=True)
            STATE.tracking_down_since = None
        return result


def _uri() -> str:
    import mlflow

    return mlflow.get_tracking_uri()


def artifact_location(uri: str | None, name: str) -> str | None:
    """Where a new experiment of a sqlite store keeps its artifacts: beside the database file. (MLflow's default
    is ./mlruns of whatever directory the first run happened to start in, so a store's artifacts would end up
    scattered, or inside a temporary dir that is later deleted.) None for other stores: the server decides."""
    if not uri or not uri.startswith("sqlite:///"):
        return None
    import re

    db = Path(uri[len("sqlite:///"):])
    return str(db.parent / "mlartifacts" / (re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "experiment"))


# MLflow 3 opens an experiment without this tag in its GenAI view (traces, "evaluation runs"); ours are classic
# model experiments: runs with params, metrics and artifacts. The UI's own switch sets the same tag.
EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")
# What decides the view of a link whatever the tag or the browser's last choice (kept in its local storage).
UI_VIEW = "workflowType=machine_learning"
UI_ADDRESS = "http://127.0.0.1:5000"  # where `make ui` serves the project's store
# A saved view of the runs table (the UI's "Views" menu; a link opens it with viewStateShareKey): the factors
# and the key metrics as columns, a run name wide enough to read the overrides. Without it the table shows
# only names, dates and durations.
VIEW_KEY = "factors"
VIEW_PARAMS = ("plan.name", "case.name", "light.name", "occluder.name", "sensor.name", "camera.name")
VIEW_METRICS = ("confidence_mean", "recall", "difficulty")


def saved_view() -> tuple[str, str]:
    """The experiment tag of the saved view: MLflow's envelope {name, createdAt, state}, state a JSON string
    of the runs table's UI state (column keys as the UI writes them: params.`KEY`, metrics.`KEY`)."""
    import json

    columns = [f"metrics.`{k}`" for k in VIEW_METRICS] + [f"params.`{k}`" for k in VIEW_PARAMS]
    # The UI applies widths only to the columns of columnOrder (its own ids: run name, created, duration).
    order = ["attributes.`Run Name`", "runDateAndNestInfo", "duration", *columns]
    state = {"selectedColumns": columns, "columnOrder": order, "columnWidths": {"attributes.`Run Name`": 340}}
    envelope = {"name": "factors and key metrics", "createdAt": int(time.time() * 1000), "state": json.dumps(state)}
    return f"mlflow.sharedViewState.{VIEW_KEY}", json.dumps(envelope)


def experiment_tags() -> dict[str, str]:
    return dict([EXPERIMENT_KIND, saved_view()])


def experiment_id(mlc, name: str) -> str:
    def get_or_create():
        exp = mlc.get_experiment_by_name(name)
        if exp is not None:
            for key, value in experiment_tags().items():  # an experiment made by an older version lacks them
                if key not in exp.tags:
                    mlc.set_experiment_tag(exp.experiment_id, key, value)
            return exp.experiment_id
        try:
            return mlc.create_experiment(name, artifact_location=artifact_location(
                getattr(mlc, "tracking_uri", None), name), tags=experiment_tags())
        except Exception:  # another worker created it first
            exp = mlc.get_experiment_by_name(name)
            if exp is None:
                raise
            return exp.experiment_id

    return retry(get_or_create)


def ui_link(uri: str | None, experiment: str, run_id: str | None = None, view: bool = True) -> str:
    """The MLflow UI's page of an experiment (in the runs view, with the saved view when `view`) or of one of
    its runs. A tracking server serves its own UI; a local store is served by `make ui` or `ui_command`."""
    uri = tracking_uri(uri)
    base = uri.rstrip("/") if uri.startswith(("http://", "https://")) else UI_ADDRESS
    if run_id:
        return f"{base}/#/experiments/{experiment}/runs/{run_id}?{UI_VIEW}"
    return f"{base}/#/experiments/{experiment}/runs?{UI_VIEW}" + (f"&viewStateShareKey={VIEW_KEY}" if view else "")


def ui_command(uri: str | None) -> str | None:
    """The command that serves a local store's UI at UI_ADDRESS (None for a tracking server: it has its UI)."""
    uri = tracking_uri(uri)
    if uri.startswith(("http://", "https://")):
        return None
    if uri == f"sqlite:///{OUTPUTS_DIR / 'mlflow.db'}":
        return "make ui"
    return f"mlflow ui --backend-store-uri {uri} --host 127.0.0.1 --port 5000"


@functools.lru_cache(maxsize=1)
def git_commit() -> str:
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PROJECT_ROOT, capture_output=True, text=True,
                             timeout=5).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=PROJECT_ROOT,
                               capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (sha or "unknown") + ("-dirty" if dirty else "")


def flatten(node: Any, prefix: str = "") -> dict[str, str]:
    """Flatten a nested config into dotted keys with string values (MLflow params)."""
    out: dict[str, str] = {}
    if isinstance(node, dict):
        for key, value in node.items():
            out.update(flatten(value, f"{prefix}{key}."))
    elif isinstance(node, list) and any(isinstance(v, (dict, list)) for v in node):
        for k, value in enumerate(node):
            out.update(flatten(value, f"{prefix}{k}."))
    else:
        out[prefix[:-1]] = str(node)[:6000]
    return out


def config_params(cfg: DictConfig) -> dict[str, str]:
    container = OmegaConf.to_container(cfg, resolve=True)
    container.pop("hydra", None)
    return flatten(container)


def file_digest(path: str | Path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def config_hash(cfg: DictConfig, plan_digest: str = "") -> str:
    """Identity of a job: the composed config without the keys that do not change its result, plus the
    content of its plan file (an edited plan is a different job, though its name is the same)."""
    import hashlib
    import json

    container = OmegaConf.to_container(cfg, resolve=True)
    for key in ("hydra", "resume", "tracking"):
        container.pop(key, None)
    if isinstance(container.get("detector"), dict):  # where `models:/` entries are looked up: the tracking store
        container["detector"].pop("registry", None)
    if plan_digest:
        container["plan_sha256"] = plan_digest
    return hashlib.sha256(json.dumps(container, sort_keys=True, default=str).encode()).hexdigest()[:16]


def describes_run(override: str) -> bool:
    """Whether an override changes what runs: `resume` and `tracking.*` (where it is logged) do not."""
    key = override.split("=", 1)[0].lstrip("+~")
    return key != "resume" and not key.startswith("tracking.") and key != "tracking"


NAME_MAX = 250  # MLflow's runs.name column: sqlite ignores the length, PostgreSQL refuses a longer name


def fit_name(name: str) -> str:
    """A run name MLflow's database takes: cut to NAME_MAX characters (its params keep every override)."""
    return name if len(name) <= NAME_MAX else name[:NAME_MAX - 3] + "..."


def run_name(task_overrides: list[str]) -> str:
    """A run's name: the overrides that change what runs (a store's path in every name hides the factors)."""
    return fit_name(" ".join(o for o in task_overrides if describes_run(o)))


def sweep_key(task_overrides: list[str]) -> str:
    """Identity of a sweep: its task overrides, sorted, without `resume` and `tracking.*` (the same sweep
    resumed, or pointed at another store, is the same sweep)."""
    import hashlib
    import json

    kept = sorted(o for o in task_overrides if describes_run(o))
    return hashlib.sha256(json.dumps(kept).encode()).hexdigest()[:16]


def finished_run(cfg: DictConfig, digest: str) -> str | None:
    """The id of a FINISHED run of the same config in this experiment, if any."""
    runs = runs_of_config(cfg, digest, "FINISHED", 1)
    return runs[0].info.run_id if runs else None


def runs_of_config(cfg: DictConfig, digest: str, status: str, limit: int) -> list:
    """Runs of this config (by its hash) in the config's experiment with the given status."""
    mlc = client(cfg.tracking.uri)
    exp = retry(lambda: mlc.get_experiment_by_name(cfg.tracking.experiment))
    if exp is None:
        return []
    return retry(lambda: mlc.search_runs([exp.experiment_id], max_results=limit,
                                         filter_string=f"tags.config_hash = '{digest}' and attributes.status = '{status}'"))


def supersede(mlc, experiment_id: str, digest: str, new_run_id: str) -> list[str]:
    """A resumed job replaces the runs of the same config that never finished (left RUNNING by a killed
    process, or FAILED/KILLED): they are marked KILLED if still RUNNING, tagged `superseded_by` and deleted
    (MLflow's soft delete: `mlflow runs restore --run-id ID` brings one back). Returns their ids."""
    runs = retry(lambda: mlc.search_runs([experiment_id], filter_string=f"tags.config_hash = '{digest}'",
                                         max_results=1000))
    gone = []
    for r in runs:
        rid = r.info.run_id
        if rid == new_run_id or r.info.status == "FINISHED":
            continue
        if r.info.status in ("RUNNING", "SCHEDULED"):
            retry(lambda rid=rid: mlc.set_tag(rid, "error", "the process ended without closing the run "
                                                            "(killed); superseded by a resumed run"))
            retry(lambda rid=rid: mlc.set_terminated(rid, "KILLED"))
        retry(lambda rid=rid: mlc.set_tag(rid, "superseded_by", new_run_id))
        retry(lambda rid=rid: mlc.delete_run(rid))
        gone.append(rid)
    return gone


def find_parent(mlc, experiment_id: str, key: str):
    """The latest parent run of the sweep with this key (see sweep_key), or None."""
    runs = retry(lambda: mlc.search_runs(
        [experiment_id], filter_string=f"tags.sweep = 'parent' and tags.sweep_key = '{key}'", max_results=1,
        order_by=["attributes.start_time DESC"]))
    return runs[0] if runs else None


PENDING_FILE = "tracking_pending.jsonl"


class JobRun:
    """The MLflow run of one job. Logging goes through the client (no global active run), so a sweep's
    parent run and the jobs of one process never interfere.

    With `pending` set (a file in the job's dir), a call the tracking server could not take (TrackingAway)
    is kept there instead of failing the job: the job finishes its frames and files, and resume=true logs
    the kept calls later (replay_pending) without rendering again."""

    def __init__(self, mlc, run_id: str, experiment_id: str | None = None, pending: Path | None = None):
        self.mlc, self.run_id, self.experiment_id, self.pending = mlc, run_id, experiment_id, pending
        self.kept = 0  # calls kept in the pending file

    def _call(self, op: str, *args) -> None:
        try:
            getattr(self, "_" + op)(*args)
        except TrackingAway:
            if self.pending is None:
                raise
            import json

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
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        batch = [Metric(k, float(v), now, step) for k, v in metrics.items()]
        for k in range(0, len(batch), 900):
            retry(lambda part=batch[k:k + 900]: self.mlc.log_batch(self.run_id, metrics=part))

    def log_series(self, key: str, values, steps=None) -> None:
        """A whole trajectory metric in few requests."""
        steps = range(len(values)) if steps is None else steps
        self._call("log_series", key, [float(v) for v in values], [int(s) for s in steps])

    def _log_series(self, key, values, steps) -> None:
        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        batch = [Metric(key, v, now, s) for s, v in zip(steps, values)]
        for k in range(0, len(batch), 900):
            retry(lambda part=batch[k:k + 900]: self.mlc.log_batch(self.run_id, metrics=part))

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

    def _end(self, status) -> None:
        retry(lambda: self.mlc.set_terminated(self.run_id, status))


def kept_run(cfg: DictConfig, digest: str) -> tuple[str, Path] | None:
    """An unfinished run of this config whose job finished its outputs while the tracking server was away
    (its pending file ends with the run's end): (run id, pending file), or None."""
    import json

    for r in runs_of_config(cfg, digest, "RUNNING", 100):
        pending = Path(r.data.tags.get("output_dir", "")) / PENDING_FILE
        if r.data.tags.get("output_dir") and pending.is_file():
            lines = pending.read_text().splitlines()
            if lines and json.loads(lines[-1]) == ["end", "FINISHED"]:
                return r.info.run_id, pending
    return None


def replay_pending(cfg: DictConfig, run_id: str, pending: Path) -> None:
    """Log the calls a job kept while the server was away, in order, into its run (which ends FINISHED)."""
    import json

    run = JobRun(client(cfg.tracking.uri), run_id)
    for line in pending.read_text().splitlines():
        op, *args = json.loads(line)
        getattr(run, "_" + op)(*args)
    pending.rename(pending.with_name(PENDING_FILE + ".logged"))


def start_job_run(cfg: DictConfig, run_name: str, tags: dict[str, str], parent_run_id: str | None) -> JobRun:
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
    for k in range(0, len(params), 100):
        retry(lambda part=params[k:k + 100]: mlc.log_batch(job.run_id, params=part))
    return job


def log_report(mlc, run_id: str, folder: str | Path, artifact_path: str = "report") -> None:
    """Log a report folder (report.md and its figures) with report.html written beside report.md: the page
    the MLflow UI's artifact preview shows with its figures (it shows neither a markdown file's images nor
    files an HTML page links to)."""
    from garage_exp.tracking.page import html_page

    if (Path(folder) / "report.md").is_file():
        html_page(Path(folder) / "report.md")
    retry(lambda: mlc.log_artifacts(run_id, str(folder), artifact_path))


def write_parent(sweep_dir: str | Path, run_id: str) -> None:
    path = Path(sweep_dir)
    path.mkdir(parents=True, exist_ok=True)
    (path / PARENT_FILE).write_text(run_id)


def read_parent(sweep_dir: str | Path) -> str | None:
    path = Path(sweep_dir) / PARENT_FILE
    return path.read_text().strip() if path.is_file() else None


RESUMED_FILE = "mlflow_resumed_run_ids"


def add_resumed(sweep_dir: str | Path, run_id: str) -> None:
    """Record a finished run that a resumed sweep skipped (one line per run; appends are atomic enough for
    short lines from several workers)."""
    with open(Path(sweep_dir) / RESUMED_FILE, "a") as fh:
        fh.write(run_id + "\n")


def read_resumed(sweep_dir: str | Path) -> list[str]:
    path = Path(sweep_dir) / RESUMED_FILE
    return sorted(set(path.read_text().split())) if path.is_file() else []


def clear_resumed(sweep_dir: str | Path) -> None:
    """A sweep starting in a used sweep dir must not count the skips of an earlier one."""
    (Path(sweep_dir) / RESUMED_FILE).unlink(missing_ok=True)


def links(uri: str | None = None) -> str:
    """Where each experiment of a store opens in the UI (`make ui` prints this before it starts the UI)."""
    mlc = client(uri)
    exps = [e for e in retry(mlc.search_experiments)  # MLflow's own empty "Default" is noise
            if e.name != "Default" or retry(lambda e=e: mlc.search_runs([e.experiment_id], max_results=1))]
    if not exps:
        return f"garage_exp: no experiment in {tracking_uri(uri)} yet (make run, or python -m garage_exp ...)"
    lines = [f"garage_exp: the MLflow UI of {tracking_uri(uri)}; each experiment in the runs view:"]
    lines += [f"  {e.name}: {ui_link(uri, e.experiment_id, view=saved_view()[0] in e.tags)}"
              for e in sorted(exps, key=lambda e: e.name)]
    return "\n".join(lines)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(prog="python -m garage_exp.tracking.runs", description=links.__doc__)
    ap.add_argument("--uri", default=None, help="the MLflow store (default: $MLFLOW_TRACKING_URI or outputs/mlflow.db)")
    print(links(ap.parse_args().uri))
