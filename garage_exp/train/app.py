"""The train entry point: check everything (config, data, labels, base), then train, track and register.

Bad input is one line on stderr and exit code 2 with nothing written: no MLflow run, no registered version, no
output dir (Hydra makes one before the task starts; it is removed while it holds only Hydra's files).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from garage_exp.core.plain import settings
from garage_exp.core import shell
from garage_exp.core.errors import GarageError, check_range
from garage_exp.train import schema

COMMAND = shell.Command("garage_exp.train", "train", (schema.register,))


def check_train(cfg: DictConfig) -> None:
    """The `train` config's values (the schema checked the types; unknown keys are refused here)."""
    from garage_exp.core.schema_check import refuse_unknown_keys

    refuse_unknown_keys(cfg, schema.TrainConf)
    check_range(cfg.epochs, 1, 10_000, "epochs")
    check_range(cfg.batch, 1, 4096, "batch")
    check_range(cfg.freeze, 0, 1000, "freeze")
    check_range(cfg.bn_calibrate, 0, 100_000, "bn_calibrate")
    if cfg.warmup_bias_lr is not None:
        check_range(cfg.warmup_bias_lr, 0.0, 1.0, "warmup_bias_lr")
    check_range(cfg.workers, 0, 64, "workers")
    check_range(cfg.seed, 0, 2**31 - 1, "seed")
    check_range(cfg.imgsz, 32, 4096, "imgsz")
    if int(cfg.imgsz) % 32:
        raise GarageError(f"{cfg.imgsz} is not a multiple of 32 (the network's largest stride)", "imgsz")
    device = str(cfg.device)
    if not (device in ("auto", "cpu", "mps") or device.replace("cuda:", "").replace(",", "").isdigit()):
        raise GarageError(f"{device!r}: use auto, cpu, a GPU index (0) or cuda:N", "device")
    optimizers = ("auto", "SGD", "Adam", "Adamax", "AdamW", "NAdam", "RAdam", "RMSprop", "MuSGD")
    if str(cfg.optimizer) not in optimizers:
        raise GarageError(f"{cfg.optimizer!r} is not one of {', '.join(optimizers)}", "optimizer")
    if cfg.lr0 is not None:
        check_range(cfg.lr0, 1e-7, 1.0, "lr0")
        if str(cfg.optimizer) == "auto":
            raise GarageError("lr0 needs a named optimizer (ultralytics' auto sets its own)", "lr0")
    if cfg.register and not str(cfg.registered_name).strip():
        raise GarageError("empty name", "registered_name")


def run_name(cfg: DictConfig, plan) -> str:
    if cfg.name:
        return str(cfg.name)
    return f"{Path(str(cfg.base)).name} on {len(plan.scenarios('train'))} scenarios, {len(plan.fit_frames)} frames"


def calibrated_base(cfg: DictConfig, plan, base, out: Path):
    """The base with its BatchNorms calibrated on `bn_calibrate` of the training's frames (seeded draw)."""
    import dataclasses
    import random

    from garage_exp.train.calibrate import calibrate

    frames = sorted(f.image for f in plan.fit_frames)
    picked = random.Random(int(cfg.seed)).sample(frames, min(int(cfg.bn_calibrate), len(frames)))
    path = calibrate(Path(base.path), picked, int(cfg.imgsz), out / "base_calibrated.pt")
    print(f"garage_exp.train: BatchNorms calibrated on {len(picked)} training frames: {path}")
    return dataclasses.replace(base, path=str(path))


def train(cfg: DictConfig) -> dict:
    """Check, then train, log and register; returns what result.json holds."""
    from garage_exp.train.base import check_names, load_base
    from garage_exp.train.data import plan_data, write_data

    out = Path(HydraConfig.get().runtime.output_dir)
    check_train(cfg)  # bad input: the shell removes the run dir and says it in one line
    plan = plan_data(cfg)
    base = load_base(str(cfg.base), cfg.tracking.uri)
    check_names(base, plan.names)
    if cfg.bn_calibrate and base.kind != "pt":
        raise GarageError("bn_calibrate calibrates a .pt base's BatchNorms; a model YAML has none trained",
                          "bn_calibrate")
    from garage_exp.tracking import runs as tracking
    from garage_exp.train.fit import fit, register

    data_yaml = write_data(plan, out / "data")
    if cfg.bn_calibrate:
        base = calibrated_base(cfg, plan, base, out)
    tags = {"base": str(cfg.base), "study": str(cfg.study or ""), "output_dir": str(out), "kind": "train"}
    run = tracking.start_job_run(settings(cfg), run_name(cfg, plan), tags, None)
    # ends FINISHED, or KILLED/FAILED with the error (also when logging or registering fails)
    with tracking.tracked_run(run):
        for name in ("manifest.csv", "data.yaml", "train.txt", "val.txt"):
            run.log_artifact(out / "data" / name, "data")
        run.log_metrics({"train_frames": len(plan.train), "replay_frames": len(plan.replay),
                         "val_frames": len(plan.val), "train_scenarios": len(plan.scenarios("train")), "val_scenarios": len(plan.scenarios("val"))})
        result = fit(cfg, plan, base, data_yaml, out, run)
        weights_dir = out / "weights"
        weights_dir.mkdir(exist_ok=True)
        weights = weights_dir / "best.pt"
        shutil.copyfile(result["weights"], weights)
        run.log_artifact(weights, "weights")
        results_csv = out / "ultralytics" / "results.csv"
        if results_csv.is_file():
            run.log_artifact(results_csv)
        run.log_metrics({"train_images_per_s": result["images_per_s"], "train_wall_s": result["wall_s"],
                         **{f"final/{k}": v for k, v in result["metrics"].items()}})
        run.set_tag("device", result["device"])
        mlc = run.mlc
        version = None
        if cfg.register:
            artifact_uri = mlc.get_run(run.run_id).info.artifact_uri
            version = register(run.run_id, artifact_uri, cfg, base, plan, mlc)
            run.set_tag("registered_model", f"models:/{cfg.registered_name}/{version}")
    summary = {"run_id": run.run_id, "weights": str(weights), "version": version,
               "model": f"models:/{cfg.registered_name}/{version}" if version else str(weights),
               "metrics": result["metrics"], "images_per_s": result["images_per_s"], "wall_s": result["wall_s"],
               "train_frames": len(plan.train), "replay_frames": len(plan.replay), "val_frames": len(plan.val),
               "epochs": int(cfg.epochs), "imgsz": int(cfg.imgsz), "device": result["device"]}
    (out / "result.json").write_text(json.dumps(summary, indent=1))
    m = result["metrics"]
    print(f"garage_exp.train: {len(plan.fit_frames)} training frames ({len(plan.replay)} replay), "
          f"{len(plan.val)} validation frames; mAP50 {m.get('metrics/mAP50_B', float('nan')):.3f}, recall "
          f"{m.get('metrics/recall_B', float('nan')):.3f}; {result['images_per_s']:.1f} images/s on {result['device']}")
    print(f"garage_exp.train: weights {weights}" + (f"; registered as {summary['model']} "
                                                     f"(use detector.models=[{summary['model']}])" if version else ""))
    return summary


def cli(argv: list[str] | None = None) -> None:
    """`python -m garage_exp.train overrides...`. Exit codes: 0 done; 2 bad input (one line, nothing written or
    registered); 1 a crash (traceback); 130 Ctrl-C, 143 SIGTERM (a scheduler's limit, the loop stopped: the
    training's run ends KILLED, not RUNNING)."""
    COMMAND.run(train, argv)
