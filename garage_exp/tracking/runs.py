"""MLflow: one run per job, a parent run per sweep, FAILED runs that keep their error.

This module is the tracking API the layers above use (`from garage_exp.tracking import runs as tracking`):
it finds a config's earlier runs (to skip, resume or supersede them) and names the parts, each in its module:
- `client.py`: the MLflow client of a store, and retry() across a locked sqlite store or an absent server;
- `experiments.py`: an experiment found or created with its tags and artifact place;
- `provenance.py`: a job's config hash and params, run names, sweep keys, the git commit (no MLflow);
- `jobrun.py`: `JobRun`, a job's run logged by run id, kept in a file while the server is away;
- `sweepfiles.py`: the files a sweep keeps for its workers (parent run id, resumed runs);
- `ui.py`: links into the MLflow UI and its saved view (`python -m garage_exp.tracking.ui`).
"""

from __future__ import annotations

import json
from pathlib import Path


from garage_exp.tracking.client import (TRANSIENT, UNREACHABLE, TrackingAway, client, existing_client, retry, tracking_uri,
                                       tracking_wait)
from garage_exp.tracking.experiments import artifact_location, experiment_id
from garage_exp.tracking.jobrun import (PENDING_FILE, JobRun, UnloggedRun, log_report, replay_pending,
                                       start_job_run, tracked_run)
from garage_exp.tracking.provenance import (NAME_MAX, config_hash, config_params, describes_run, file_digest,
                                            fit_name, flatten, git_commit, run_name, sweep_key)
from garage_exp.tracking.sweepfiles import (PARENT_FILE, RESUMED_FILE, add_resumed, clear_resumed, read_parent,
                                            read_resumed, write_parent)
from garage_exp.tracking.ui import (EXPERIMENT_KIND, UI_ADDRESS, UI_VIEW, VIEW_KEY, VIEW_METRICS, VIEW_PARAMS,
                                    experiment_tags, links, saved_view, ui_command, ui_link)


def finished_run(cfg, digest: str) -> str | None:
    """The id of a FINISHED run of the same config in this experiment, if any."""
    runs = runs_of_config(cfg, digest, "FINISHED", 1)
    return runs[0].info.run_id if runs else None


def runs_of_config(cfg, digest: str, status: str, limit: int) -> list:
    """Runs of this config (by its hash) in the config's experiment with the given status."""
    mlc = client(cfg.tracking.uri)
    exp = retry(lambda: mlc.get_experiment_by_name(cfg.tracking.experiment))
    if exp is None:
        return []
    return retry(lambda: mlc.search_runs([exp.experiment_id], max_results=limit,
                                         filter_string=f"tags.config_hash = '{digest}' and attributes.status = '{status}'"))


def kept_run(cfg, digest: str) -> tuple[str, Path] | None:
    """An unfinished run of this config whose job finished its outputs while the tracking server was away
    (its pending file ends with the run's end): (run id, pending file), or None."""
    for r in runs_of_config(cfg, digest, "RUNNING", 100):
        pending = Path(r.data.tags.get("output_dir", "")) / PENDING_FILE
        if r.data.tags.get("output_dir") and pending.is_file():
            lines = pending.read_text().splitlines()
            if lines and json.loads(lines[-1]) == ["end", "FINISHED"]:
                return r.info.run_id, pending
    return None


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


__all__ = [
    "EXPERIMENT_KIND", "JobRun", "UnloggedRun", "NAME_MAX", "PARENT_FILE", "PENDING_FILE", "RESUMED_FILE", "TRANSIENT",
    "TrackingAway", "UI_ADDRESS", "UI_VIEW", "UNREACHABLE", "VIEW_KEY", "VIEW_METRICS", "VIEW_PARAMS",
    "add_resumed", "artifact_location", "clear_resumed", "client", "config_hash", "config_params",
    "describes_run", "existing_client", "experiment_id", "experiment_tags", "file_digest", "find_parent", "finished_run", "fit_name",
    "flatten", "git_commit", "kept_run", "links", "log_report", "read_parent", "read_resumed", "replay_pending",
    "retry", "run_name", "runs_of_config", "saved_view", "start_job_run", "supersede", "sweep_key", "tracked_run",
    "tracking_uri",
    "tracking_wait", "ui_command", "ui_link", "write_parent",
]
