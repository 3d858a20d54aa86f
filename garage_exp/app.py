"""The Hydra application: compose the factors, check them, run one job, return its difficulty for a sweeper.

Bad input never costs a run: `preflight` checks a job's config, plan, assets, weights and case (everything up
to the renderer) before anything is written, and `cli` turns every input error - ours (GarageError) and
Hydra's (unknown level, wrong type, bad override) - into one line on stderr and exit code 2.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import signal
import sys
import traceback
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from garage_exp import config as schema
from garage_exp import tracking
from garage_exp.config import FOVY_RANGE, RESOLUTION_RANGE
from garage_exp.errors import GarageError, check_range
from garage_exp.paths import OUTPUTS_DIR, PLANS_DIR, PROJECT_ROOT

log = logging.getLogger("garage_exp")

if not OmegaConf.has_resolver("garage_root"):
    OmegaConf.register_new_resolver("garage_root", lambda: str(PROJECT_ROOT))
schema.register()

EXIT_INPUT = 2  # bad input: one line on stderr, nothing logged
EXIT_FAILED_JOBS = 1  # a sweep ran to its end but some of its jobs failed (the summary lists them)


def quote_numeric_choices(argv: list[str]) -> list[str]:
    """Hydra parses `case=1` as an int and rejects it as a group choice; the research names its cases
    1, 2, 3, so quote bare integer choices of config groups (`case=1,2` -> `case='1','2'`)."""
    groups = {p.name for p in (PROJECT_ROOT / "conf").iterdir() if p.is_dir()}
    out = []
    for arg in argv:
        key, eq, value = arg.partition("=")
        if eq and key.lstrip("+~") in groups and any(v.strip().isdigit() for v in value.split(",")):
            arg = key + "=" + ",".join(f"'{v.strip()}'" if v.strip().isdigit() else v for v in value.split(","))
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


# ---------------------------------------------------------------------------------------------- preflight

_CACHE: dict = {}  # plan path -> (stat key, classified); vehicles dir -> VehicleLibrary (sweeps check many jobs)


def _classified(path: Path):
    from garage_exp.plan import classify, load_plan

    try:
        st = path.stat()
        key = (st.st_mtime_ns, st.st_size)
    except OSError:
        key = None
    hit = _CACHE.get(("plan", path))
    if key is not None and hit is not None and hit[0] == key:
        return hit[1]
    classified = classify(load_plan(path))  # bad plans fail here with the file and the place
    if key is not None:
        _CACHE[("plan", path)] = (key, classified)
    return classified


def _library():
    from garage_exp.assets.locate import vehicles_dir
    from garage_exp.assets.vehicles import VehicleLibrary

    root = vehicles_dir()  # missing assets fail here, saying what to set or run
    if ("library", root) not in _CACHE:
        _CACHE[("library", root)] = VehicleLibrary(root)
    return _CACHE[("library", root)]


def check_config(cfg: DictConfig) -> None:
    """Value checks that need neither the plan nor the assets (the schema already checked the types)."""
    from garage_exp.detect.matching import MATCH_MODES
    from garage_exp.scene.lamps import check_light
    from garage_exp.scene.structure import check_garage
    from garage_exp.sensor import make_sensor

    for key in ("seed", "light.seed", "palette.seed"):
        value = OmegaConf.select(cfg, key)
        if value is not None and int(value) < 0:
            raise GarageError(f"{value} is negative (seeds are >= 0)", key)
    check_garage(cfg.garage)
    check_light(cfg.light)
    check_range(cfg.palette.parked_occupancy, 0.0, 1.0, "palette.parked_occupancy")
    if not cfg.camera.cameras:
        raise GarageError("the rig has no camera", "camera.cameras")
    for k, cam in enumerate(cfg.camera.cameras):
        check_range(cam.fovy, *FOVY_RANGE, f"camera.cameras.{k}.fovy", f"fovy {cam.fovy} degrees")
        for side in ("width", "height"):
            check_range(cam[side], *RESOLUTION_RANGE, f"camera.cameras.{k}.{side}", f"{side} {cam[side]} px")
    if cfg.case.motion.actor and not float(cfg.case.motion.step) > 0:
        raise GarageError(f"step must be positive, got {cfg.case.motion.step}", "case.motion.step")
    det = cfg.detector
    if not det.models:
        raise GarageError("no detector models given", "detector.models")
    if not 0.0 <= float(det.conf) < 1.0:
        raise GarageError(f"conf {det.conf} is outside [0, 1)", "detector.conf")
    if not 0.0 < float(det.iou) <= 1.0:
        raise GarageError(f"iou {det.iou} is outside (0, 1]", "detector.iou")
    check_range(det.threshold, 0.0, 1.0, "detector.threshold")
    check_range(det.imgsz, 32, 4096, "detector.imgsz")
    if det.match not in MATCH_MODES:
        raise GarageError(f"unknown match {det.match!r} ({' | '.join(MATCH_MODES)})", "detector.match")
    if cfg.renderer.backend != "sapien":
        raise GarageError(f"unknown backend {cfg.renderer.backend!r} (sapien)", "renderer.backend")
    check_range(cfg.renderer.max_lights, 1, 10, "renderer.max_lights")
    if cfg.renderer.save_frames not in ("all", "key", "none"):
        raise GarageError(f"unknown save_frames {cfg.renderer.save_frames!r} (all | key | none)",
                          "renderer.save_frames")
    make_sensor(cfg.sensor)
    from garage_exp.scene.modifiers import allowed_modules

    allowed = allowed_modules()
    for group, spec in (cfg.get("modifiers") or {}).items():
        target = str((spec or {}).get("_target_") or "")
        if target and not target.startswith(allowed):
            raise GarageError(f"_target_ {target!r} is not a scene modifier (allowed modules: "
                              f"{', '.join(allowed)}; more via $GARAGE_EXP_MODIFIER_MODULES)",
                              f"modifiers.{group}")


def preflight(cfg: DictConfig):
    """Check one job's inputs before anything is written; GarageError (one line, naming the file or key)
    on the first problem. A dry run checks the config and the plan; a real job also the detector weights,
    the vehicle assets, and builds its scene description (garage, case, palette, modifiers, cameras) - all
    but rendering, in ~0.1 s. Returns (plan path, classified plan)."""
    plan_path = resolve_plan_path(cfg.plan)
    classified = _classified(plan_path)
    check_config(cfg)
    if cfg.dry_run:
        return plan_path, classified
    import numpy as np

    from garage_exp.detect.detector import model_format, resolve_model
    from garage_exp.experiment import build_scene

    for entry in cfg.detector.models:
        model_format(resolve_model(entry))  # missing weights fail here (nothing is downloaded)
    build_scene(cfg, classified, _library(), np.random.default_rng(int(cfg.seed)))
    return plan_path, classified


def _remove_untouched(out: Path) -> None:
    """Hydra makes a job's dir (config copies, log) before the job starts; a job refused for bad input
    leaves nothing behind. Only a dir holding nothing but Hydra's own files is removed."""
    try:
        if not out.is_dir() or any(p.name != ".hydra" and p.suffix != ".log" for p in out.iterdir()):
            return
        shutil.rmtree(out)
        parent = out.parent  # outputs/runs/<date>/<time>: drop the date level too when it is empty
        if parent.parent == OUTPUTS_DIR / "runs" and not any(parent.iterdir()):
            parent.rmdir()
    except OSError:
        pass


# ---------------------------------------------------------------------------------------------- one job

def run_job(cfg: DictConfig) -> float:
    """Run one job and return its difficulty (1 - mean composite confidence), NaN for a plan-only job."""
    hc = HydraConfig.get()
    out = Path(hc.runtime.output_dir)
    multirun = hc.mode == RunMode.MULTIRUN
    try:
        plan_path, classified = preflight(cfg)  # bad input fails here, before anything is logged
    except GarageError:
        _remove_untouched(out)
        raise
    digest = tracking.config_hash(cfg, tracking.file_digest(plan_path))
    if cfg.resume:
        done = tracking.finished_run(cfg, digest)
        if done:
            print(f"garage_exp: skipped {run_name(cfg)!r}: finished before as run {done}")
            if multirun:
                tracking.add_resumed(hc.sweep.dir, done)  # the sweep report counts it
            return math.nan
    parent = tracking.read_parent(hc.sweep.dir) if multirun else None
    tags = {"plan": classified.plan.name, "overrides": " ".join(hc.overrides.task), "case": str(cfg.case.name),
            "output_dir": str(out), "config_hash": digest, "host": os.uname().nodename, "pid": str(os.getpid())}
    run = tracking.start_job_run(cfg, run_name(cfg), tags, parent)
    try:
        from garage_exp.plan.draw import draw_map  # matplotlib: not before the input is known to be good

        if cfg.resume:  # the runs this one replaces (left RUNNING by a killed sweep, or failed)
            gone = tracking.supersede(run.mlc, tracking.experiment_id(run.mlc, cfg.tracking.experiment), digest,
                                      run.run_id)
            if gone:
                print(f"garage_exp: rerunning {run_name(cfg)!r}: replaces unfinished run(s) {', '.join(gone)}")
        (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
        run.log_artifact(out / "config.yaml")
        run.log_artifact(draw_map(classified, out / "plan_map.png"))
        if cfg.dry_run:
            difficulty = math.nan
        else:
            from garage_exp.experiment import run_experiment

            difficulty = run_experiment(cfg, classified, out, run)
    except BaseException as exc:
        try:
            run.set_tag("error", f"{type(exc).__name__}: {exc}".strip())
            run.log_text(traceback.format_exc(), "error.txt")
        finally:
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
            sys.exit(EXIT_INPUT)
    except Exception:
        if not multirun:
            raise
        # The run is already marked FAILED with its error; the sweep goes on.
        log.error("job failed:\n%s", traceback.format_exc())
    return math.nan


# ---------------------------------------------------------------------------------------------- command line

class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler's time limit, `kill`): handled like Ctrl-C, so the job's run ends KILLED and its
    partial frame table is kept."""


def _on_sigterm(signum, frame):
    raise Terminated(f"signal {signum} (SIGTERM)")


def input_error(exc: BaseException) -> str | None:
    """One line for an input error (ours or Hydra's), None for anything else (a bug: traceback)."""
    import yaml
    from hydra.errors import CompactHydraException, HydraException
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(exc, GarageError):
        return str(exc)
    if isinstance(exc, yaml.YAMLError):  # a config file that is not YAML, or asks for Python objects
        return one_line(str(exc))
    if isinstance(exc, OmegaConfBaseException) or (
            isinstance(exc, HydraException) and (isinstance(exc, CompactHydraException)
                                                 or not str(exc).startswith("Error executing job"))):
        text = str(exc)
        override = getattr(exc, "override", None)  # OverrideParseException: name the bad override
        if override and override not in text:
            text = f"override {override!r}: {text}"
        cause = exc.__cause__
        if isinstance(cause, OmegaConfBaseException) and str(cause).split("\n")[0] not in text:
            text += "\n" + str(cause)
        return one_line(text)
    return None


def one_line(text: str) -> str:
    """Hydra's and OmegaConf's messages in one line: indented details (full_key, types) folded in, lists of
    available options joined with commas."""
    parts: list[str] = []
    options: list[str] = []
    for raw in text.split("Config search path:")[0].splitlines():
        line = raw.strip()
        if not line or line.startswith(("reference_type", "object_type", "Set the environment variable")):
            continue
        if raw.startswith("\t") and parts and parts[-1].endswith(":"):  # "Available options in 'light':"
            if not line.endswith("_schema"):  # the structured-config schemas are not levels to choose
                options.append(line)
            continue
        if options:
            parts[-1] += " " + ", ".join(options)
            options = []
        if line.startswith("full_key:"):
            line = f"(key {line.split(':', 1)[1].strip()})"
        parts.append(line)
    if options:
        parts[-1] += " " + ", ".join(options)
    return " ".join(p if p.endswith((".", ":", ")")) or k == len(parts) - 1 else p + ";"
                    for k, p in enumerate(parts))


def _install_error_report() -> None:
    """Hydra prints its own errors (several lines, exit 1) from `run_and_report`; ours prints input errors as
    one line and exits 2, and leaves other errors (bugs) to Hydra's traceback. HYDRA_FULL_ERROR=1 bypasses
    both, as documented by Hydra."""
    import hydra._internal.utils as hydra_utils

    original = hydra_utils.run_and_report
    if getattr(original, "garage_exp", False):
        return

    def run_and_report(func):
        try:
            return func()
        except Exception as exc:
            if os.environ.get("HYDRA_FULL_ERROR") == "1":
                raise
            line = input_error(exc)
            if line is None:
                def reraise():
                    raise exc
                return original(reraise)
            print(f"garage_exp: {line}", file=sys.stderr)
            sys.exit(EXIT_INPUT)

    run_and_report.garage_exp = True
    hydra_utils.run_and_report = run_and_report


def cli(argv: list[str] | None = None) -> None:
    """`python -m garage_exp [-m] overrides...`. Exit codes: 0 done; 2 bad input (one line, nothing run);
    1 a sweep finished with failed jobs (its summary lists them) or a job crashed (traceback); 130 Ctrl-C,
    143 SIGTERM (the running job's run ends KILLED; resume=true finishes the sweep)."""
    from garage_exp import callbacks

    sys.argv[1:] = quote_numeric_choices(sys.argv[1:] if argv is None else list(argv))
    _install_error_report()
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        main()
    except BaseException as exc:
        callbacks.abandon_sweep(exc)  # the parent run of an interrupted sweep must not stay RUNNING
        if isinstance(exc, KeyboardInterrupt):  # the job's run already ended KILLED, its partial table kept
            terminated = isinstance(exc, Terminated)
            print(f"garage_exp: {'terminated (SIGTERM)' if terminated else 'interrupted'}; rerun the same "
                  "command with resume=true to finish the sweep", file=sys.stderr)
            sys.exit(128 + (signal.SIGTERM if terminated else signal.SIGINT))
        if isinstance(exc, ValueError) and str(exc).startswith("Only one of --run"):  # Hydra's own flag check
            print(f"garage_exp: {exc} (--cfg prints a single job's config: drop -m)", file=sys.stderr)
            sys.exit(2)
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
    sweep = callbacks.current_sweep()
    if sweep is not None and sweep.failures:
        sys.exit(EXIT_FAILED_JOBS)
