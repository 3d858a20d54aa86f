"""One training: ultralytics' own trainer (`YOLO(base).train(...)`, its progress bars as it prints them), tracked as
one MLflow run of the project's store (params, per-epoch metrics, the weights, the data manifest) and registered
as a version of `garage-detector` tagged with its base, its data and the study that found the data.

ultralytics' own MLflow callback is switched off: it would open its own run in whatever store
$MLFLOW_TRACKING_URI names. The epochs are logged here instead, by callbacks on the same trainer.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from garage_exp.core.environment import prepare_environment
from garage_exp.train.base import Base
from garage_exp.train.data import DataPlan

INTEGRATIONS = ("clearml", "comet", "dvc", "mlflow", "raytune", "tensorboard", "wandb")


def pick_device(device: str) -> str:
    """`auto`: the first GPU when torch sees one, else the CPU; anything else as given."""
    if str(device) != "auto":
        return str(device)
    import torch

    return "0" if torch.cuda.is_available() else "cpu"


def metric_key(key: str) -> str:
    """MLflow refuses parentheses in keys: metrics/mAP50(B) -> metrics/mAP50_B."""
    return key.replace("(", "_").replace(")", "")


def epoch_logger(run, n_images: int, timings: list[float]):
    """Callbacks that log each epoch's losses, validation metrics, learning rates and training throughput."""
    started = {}

    def on_train_epoch_start(trainer):
        started["t"] = time.perf_counter()

    def on_train_epoch_end(trainer):
        timings.append(time.perf_counter() - started.get("t", time.perf_counter()))

    def on_fit_epoch_end(trainer):
        # ultralytics calls this again after its last epoch, validating best.pt: that is the run's final metrics
        # (logged once training ends), not another epoch.
        if len(timings) <= started.get("logged", 0):
            return
        started["logged"] = len(timings)
        values = {**trainer.label_loss_items(trainer.tloss, prefix="train"), **(trainer.metrics or {}),
                  **(trainer.lr or {})}
        values = {metric_key(k): float(v) for k, v in values.items()}
        if timings:
            values["train_images_per_s"] = n_images / max(timings[-1], 1e-9)
        run.log_metrics(values, step=len(timings))

    return {"on_train_epoch_start": on_train_epoch_start, "on_train_epoch_end": on_train_epoch_end,
            "on_fit_epoch_end": on_fit_epoch_end}


def fit(cfg, plan: DataPlan, base: Base, data_yaml: Path, out: Path, run) -> dict:
    """Train; return the final metrics, the weights' path and the mean training throughput (images/s)."""
    prepare_environment(offline=True)
    from ultralytics import YOLO
    from ultralytics.utils import SETTINGS

    SETTINGS.update({key: False for key in INTEGRATIONS})  # our run logs the epochs (YOLO_CONFIG_DIR is ours)
    device = pick_device(cfg.device)
    model = YOLO(base.path)
    timings: list[float] = []
    for event, fn in epoch_logger(run, len(plan.fit_frames), timings).items():
        model.add_callback(event, fn)
    extra = {"optimizer": str(cfg.optimizer)}
    if cfg.lr0 is not None:
        extra["lr0"] = float(cfg.lr0)
    if cfg.warmup_bias_lr is not None:
        extra["warmup_bias_lr"] = float(cfg.warmup_bias_lr)
    start = time.perf_counter()
    model.train(**extra, data=str(data_yaml), epochs=int(cfg.epochs), imgsz=int(cfg.imgsz), batch=int(cfg.batch),
                seed=int(cfg.seed), deterministic=True, freeze=int(cfg.freeze) or None, device=device,
                workers=int(cfg.workers), project=str(out), name="ultralytics", exist_ok=True, plots=False,
                amp=device != "cpu", verbose=True)
    wall = time.perf_counter() - start
    trainer = model.trainer
    weights = Path(trainer.best) if Path(trainer.best).is_file() else Path(trainer.last)
    final = {metric_key(k): float(v) for k, v in (trainer.metrics or {}).items()}
    throughput = len(plan.fit_frames) * len(timings) / max(sum(timings), 1e-9) if timings else float("nan")
    return {"weights": weights, "metrics": final, "images_per_s": throughput, "wall_s": wall, "device": device,
            "epochs_run": len(timings)}


def register(run_id: str, artifact_uri: str, cfg, base: Base, plan: DataPlan, mlc) -> int:
    """A new version of `registered_name` whose source is the run's weights/ folder; its number."""
    from mlflow.exceptions import MlflowException

    name = str(cfg.registered_name)
    try:
        mlc.create_registered_model(name, description="Detectors trained by python -m garage_exp.train")
    except MlflowException as exc:
        if "already exists" not in str(exc).lower() and "RESOURCE_ALREADY_EXISTS" not in str(exc):
            raise
    version = mlc.create_model_version(name, f"{artifact_uri}/weights", run_id=run_id, tags=model_tags(cfg, base, plan))
    return int(version.version)


def model_tags(cfg, base: Base, plan: DataPlan) -> dict[str, str]:
    """What a version was made from: its base, its data (inputs and frame counts) and the study that found them."""
    data = {"inputs": [str(s.path) for s in plan.sources], "train_frames": len(plan.train),
            "replay_frames": len(plan.replay), "val_frames": len(plan.val),
            "train_scenarios": len(plan.scenarios("train")), "val_scenarios": len(plan.scenarios("val"))}
    return {"base": str(base.entry), "data": json.dumps(data)[:4900], "study": str(cfg.study or "")}
