"""The Hydra application: compose the factors, run one job, return its difficulty for a sweeper."""

from __future__ import annotations

import logging
import math
import sys
import traceback
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from garage_exp import config as schema
from garage_exp import tracking
from garage_exp.errors import GarageError
from garage_exp.paths import PLANS_DIR, PROJECT_ROOT

log = logging.getLogger("garage_exp")

if not OmegaConf.has_resolver("garage_root"):
    OmegaConf.register_new_resolver("garage_root", lambda: str(PROJECT_ROOT))
schema.register()


def quote_numeric_choices(argv: list[str]) -> list[str]:
    """Hydra parses `case=1` as an int and rejects it as a group choice; the research names its cases
    1, 2, 3, so quote bare integer choices of config groups (`case=1,2` -> `case='1','2'`)."""
    groups = {p.name for p in (PROJECT_ROOT / "conf").iterdir() if p.is_dir()}
    out = []
    for arg in argv:
        key, eq, value = arg.partition("=")
        if eq and key.lstrip("+~") in groups and all(v.strip().isdigit() for v in value.split(",")):
            arg = key + "=" + ",".join(f"'{v.strip()}'" for v in value.split(","))
        out.append(arg)
    return out


def resolve_plan_path(plan_cfg) -> Path:
    """`plan.file` (absolute, or relative to where the command was typed) wins over a shipped plan name."""
    if plan_cfg.file:
        return Path(hydra.utils.to_absolute_path(str(plan_cfg.file)))
    for suffix in (".yaml", ".yml", ".csv"):
        candidate = PLANS_DIR / f"{plan_cfg.name}{suffix}"
        if candidate.is_file():
            return candidate
    shipped = sorted(p.stem for p in PLANS_DIR.glob("*.*"))
    raise GarageError(f"no shipped plan named {plan_cfg.name!r} (have: {', '.join(shipped)}); "
                      "use plan.file=/path/to/plan.yaml for your own", "plan.name")


def run_name(cfg: DictConfig) -> str:
    overrides = HydraConfig.get().overrides.task
    return " ".join(overrides) if overrides else f"case={cfg.case.name} light={cfg.light.name}"


def run_job(cfg: DictConfig) -> float:
    """Run one job and return its difficulty (1 - mean composite confidence), NaN for a plan-only job."""
    from garage_exp.plan import classify, load_plan
    from garage_exp.plan.draw import draw_map

    hc = HydraConfig.get()
    out = Path(hc.runtime.output_dir)
    plan = load_plan(resolve_plan_path(cfg.plan))  # bad input fails here, before anything is logged
    classified = classify(plan)
    digest = tracking.config_hash(cfg)
    if cfg.resume:
        done = tracking.finished_run(cfg, digest)
        if done:
            print(f"garage_exp: skipped {run_name(cfg)!r}: finished before as run {done}")
            if hc.mode == RunMode.MULTIRUN:
                tracking.add_resumed(hc.sweep.dir, done)  # the sweep report counts it
            return math.nan
    parent = tracking.read_parent(hc.sweep.dir) if hc.mode == RunMode.MULTIRUN else None
    tags = {"plan": plan.name, "overrides": " ".join(hc.overrides.task), "case": str(cfg.case.name),
            "output_dir": str(out), "config_hash": digest}
    run = tracking.start_job_run(cfg, run_name(cfg), tags, parent)
    try:
        (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        run.log_artifact(out / "config.yaml")
        run.log_artifact(draw_map(classified, out / "plan_map.png"))
        if cfg.dry_run:
            difficulty = math.nan
        else:
            from garage_exp.experiment import run_experiment

            difficulty = run_experiment(cfg, classified, out, run)
    except BaseException as exc:
        run.set_tag("error", f"{type(exc).__name__}: {exc}")
        run.end("KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED")
        raise
    run.end("FINISHED")
    return difficulty


@hydra.main(version_base="1.3", config_path=str(PROJECT_ROOT / "conf"), config_name="config")
def main(cfg: DictConfig) -> float:
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    try:
        return run_job(cfg)
    except GarageError as exc:
        print(f"garage_exp: {exc}", file=sys.stderr)
        if not multirun:
            sys.exit(2)
    except Exception:
        if not multirun:
            raise
        # The run is already marked FAILED with its error; the sweep goes on.
        log.error("job failed:\n%s", traceback.format_exc())
    return math.nan
