"""One job of a run or a sweep: preflight, resume, its MLflow run, the experiment, and how the run ends."""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from garage_exp.core.plain import holds
from garage_exp.core.state import STATE
from garage_exp.tracking import runs as tracking
from garage_exp.core.exits import SweepStopped
from garage_exp.run.diskspace import NotEnoughSpace, full_disk
from garage_exp.core.errors import JobFault
from garage_exp.core import shell
from garage_exp.results.summary import JobSummary
from garage_exp.run.preflight import preflight


def name_levels(cfg: DictConfig, plan_name: str) -> None:
    """Make every `name` in the config say what runs, before it is converted and logged (the preflight calls it
    once the plan is read): `plan.name` is the name of the plan file actually loaded (with `plan.file=big.yaml`
    the group's default name `research` would stay), and a group level's name is the level composed (a user's
    `conf/light/night.yaml` without `name:`, or copied from bright.yaml, would log `light.name=bright`). A
    `GROUP.name=...` given on the command line is kept (not `plan.name`: with `plan.file` it is not what ran)."""
    hc = HydraConfig.get()
    given = {o.split("=", 1)[0].lstrip("+~") for o in hc.overrides.task}
    cfg.plan.name = plan_name
    for group, level in hc.runtime.choices.items():
        if group == "plan" or "/" in group or level is None or f"{group}.name" in given:
            continue
        node = OmegaConf.select(cfg, group, default=None)
        if isinstance(node, DictConfig) and holds(node, "name"):
            node.name = str(level)


def plan_map(classified, path: Path) -> Path:
    """The plan's map at `path`, drawn once per process and plan (matplotlib takes ~0.4 s; every job of a sweep
    on one plan would draw the same picture)."""
    import hashlib

    plan = classified.plan  # the map shows the plan's cells and the pillars classified from it
    key = hashlib.sha1(b"".join([plan.name.encode(), plan.S.tobytes(), plan.R.tobytes(), plan.C.tobytes(),
                                 repr(classified.pillars).encode()])).hexdigest()
    if key not in STATE.maps:
        from garage_exp.plan.draw import draw_map  # matplotlib: not before the input is known to be good

        draw_map(classified, path)
        STATE.maps = {**dict(list(STATE.maps.items())[-7:]), key: path.read_bytes()}  # a few plans at most
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(STATE.maps[key])
    return path


def run_name(cfg: DictConfig) -> str:
    return (tracking.run_name(list(HydraConfig.get().overrides.task))
            or f"plan={cfg.plan.name} case={cfg.case.name} light={cfg.light.name}")


def _count_finished() -> None:
    STATE.finished_jobs += 1  # the count a stopped sweep reports


def _close_on_full_disk(run, out: Path, where: str) -> None:
    """The disk is full: the job's run ends FAILED saying so. When the store shares the full disk and cannot
    record even that, the job's partial outputs and their artifact copies are deleted to make room (a failed
    job is rerun by resume=true anyway); the finished jobs' files are not touched."""
    import logging

    reason = f"disk full at {where}"
    db_log = logging.getLogger("mlflow.store.db.utils")  # logs each failed write with its traceback
    level = db_log.level
    db_log.setLevel(logging.CRITICAL)
    try:
        run.set_tag("error", reason)
        run.end("FAILED")
        return
    except Exception as exc:  # noqa: BLE001 - only a full disk is handled here
        if full_disk(exc) is None:
            raise
    finally:
        db_log.setLevel(level)
    from urllib.parse import urlparse

    for path in out.iterdir():
        if path.name != ".hydra":
            shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink(missing_ok=True)
    try:
        artifacts = run.mlc.get_run(run.run_id).info.artifact_uri
        local = Path(urlparse(artifacts).path) if artifacts.startswith(("file:", "/")) else None
        if local is not None and local.is_dir():
            shutil.rmtree(local)
    except Exception:  # noqa: BLE001 - a best effort: the job's own dir was the larger part
        pass
    run.set_tag("error", reason + " (the job's partial outputs were deleted to record this)")
    run.end("FAILED")


AWAY_HINT = "rerun the same command with resume=true once the server is back"


def kept_frames(out: Path) -> str:
    """What a job that failed mid-way kept of its frames, for its one line."""
    table = out / "frames.csv"
    try:
        rows = max(0, len(table.read_text().splitlines()) - 1)
    except OSError:
        return "no frame scored"
    return f"the {rows} frame(s) scored before it kept in {table}"


def run_job(cfg: DictConfig) -> float | JobSummary:
    """Run one job and return its difficulty (1 - mean composite confidence), NaN for a plan-only job; a
    search trial (`search.trial` set) returns its summary (results.summary.JobSummary) with its run id and dir
    instead. A tracking
    server that stays away stops the sweep (every later job would wait for it too)."""
    STATE.begin_job()  # the last job's job-scoped caches go
    try:
        return _run_job(cfg)
    except tracking.TrackingAway as exc:
        raise SweepStopped(str(exc), AWAY_HINT) from None


def _run_job(cfg: DictConfig) -> float | JobSummary:
    hc = HydraConfig.get()
    out = Path(hc.runtime.output_dir)
    multirun = shell.multirun()
    try:
        prepared = preflight(cfg, name=name_levels)  # bad input fails here, before anything is logged
    except NotEnoughSpace as exc:  # the disk filled since the sweep's own check: a sweep stops here
        if shell.refuse_job():
            raise SweepStopped(str(exc), "free space and rerun with resume=true") from None
        raise  # a single run: the command's shell says it in one line, as any bad input
    config = prepared.config  # as renamed (name_levels, in the preflight): what tracking logs and hashes
    digest = tracking.config_hash(config, tracking.file_digest(prepared.plan_path))
    if cfg.resume:
        done = tracking.finished_run(config, digest)
        if done:
            print(f"garage_exp: skipped {run_name(cfg)!r}: finished before as run {done}")
            if multirun:
                tracking.add_resumed(hc.sweep.dir, done)  # the sweep report counts it
            _count_finished()
            return math.nan
        kept = tracking.kept_run(config, digest)
        if kept:  # finished while the tracking server was away: log what it kept, do not render again
            tracking.replay_pending(config, *kept)
            print(f"garage_exp: logged {run_name(cfg)!r} from the outputs kept in {kept[1].parent} (run {kept[0]}); "
                  "not rendered again")
            _count_finished()
            return math.nan
    parent = tracking.read_parent(hc.sweep.dir) if multirun else None
    trial = cfg.search.trial
    tags = {"plan": prepared.classified.plan.name, "overrides": " ".join(hc.overrides.task), "case": str(cfg.case.name),
            "output_dir": str(out), "config_hash": digest, "host": os.uname().nodename, "pid": str(os.getpid())}
    if trial is not None:
        tags["search_trial"] = str(trial)
    if trial is not None and cfg.search.get("runs", "per_trial") == "per_search":
        run = tracking.UnloggedRun()  # one run per search: the parent holds the trials' rows (search.runs)
    else:
        run = tracking.start_job_run(config, run_name(cfg), tags, parent)
    run.pending = out / tracking.PENDING_FILE  # calls the tracking server cannot take wait there
    try:
        with tracking.tracked_run(run, traceback_file=True):
            try:
                summary = _run_body(cfg, prepared, out, run, digest)
            except Exception as exc:
                where = full_disk(exc)
                if where is None:
                    raise
                where = where or str(out)
                _close_on_full_disk(run, out, where)  # the run ends FAILED its own way: tracked_run leaves it
                raise SweepStopped(f"disk full at {where}", "free space and rerun with resume=true") from None
    except JobFault as exc:  # an expected fault: its one line says what ended and what is kept
        raise JobFault(f"{exc}; its run {run.run_id} ended FAILED, {kept_frames(out)}") from None
    if run.kept:
        raise SweepStopped(f"tracking server {tracking.tracking_uri(cfg.tracking.uri)} away: job {run_name(cfg)!r} "
                           f"finished, its outputs kept in {out}", AWAY_HINT + " (it logs them without rendering again)")
    _count_finished()
    if not multirun:  # a sweep prints its own link, to all its runs
        print(f"garage_exp: MLflow UI: {tracking.ui_link(cfg.tracking.uri, run.experiment_id, run.run_id)}")
    if trial is not None:  # the search's sweeper tells Optuna from this
        return summary.with_(run_id=run.run_id, output_dir=str(out))
    return float(summary.difficulty)


def _run_body(cfg: DictConfig, prepared, out: Path, run, digest: str) -> JobSummary:
    """What a job's run holds: the runs it replaces superseded, its config and map, its OpenSCENARIO export and
    its frames; the frames' summary."""
    trial = cfg.search.trial
    if cfg.resume:  # the runs this one replaces (left RUNNING by a killed sweep, or failed)
        gone = tracking.supersede(run.mlc, tracking.experiment_id(run.mlc, cfg.tracking.experiment), digest,
                                  run.run_id)
        if gone:
            print(f"garage_exp: rerunning {run_name(cfg)!r}: replaces unfinished run(s) {', '.join(gone)}")
    if run.run_id is not None:  # a trial without a run of its own is rerun by its overrides (the study's)
        (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        run.log_artifact(out / "config.yaml")
    if trial is None:  # a search trial's map is its study's: the parent holds it
        run.log_artifact(plan_map(prepared.classified, out / "plan_map.png"))
    if cfg.export.openscenario and trial is None:  # a search exports its hardest trials itself
        from garage_exp.run.openscenario import export

        for path in export(cfg, out / "openscenario", prepared):
            run.log_artifact(path, "openscenario")
    if cfg.dry_run:
        summary = JobSummary()  # difficulty NaN, nothing measured
    else:
        from garage_exp.run.frames import run_frames

        summary = run_frames(prepared, out, run)
    return summary
