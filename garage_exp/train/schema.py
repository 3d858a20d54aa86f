"""The schema of `python -m garage_exp.train`'s config (conf/train.yaml), registered in Hydra's ConfigStore."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from hydra.core.config_store import ConfigStore

from garage_exp.tracking.schema import TrackingConf

REGISTERED_NAME = "garage-detector"


@dataclass
class TrainConf:
    """One training. `data`, `replay` and `val` take any mix of suite directories (search.mode=suite with
    dataset=true), job outputs or their dataset/ folders (dataset=true) and YOLO data.yaml files."""

    data: list[str] = field(default_factory=list)  # the new training data, split by scenario into train and val
    val: list[str] = field(default_factory=list)  # explicit validation data; then `data` is all training
    val_fraction: float = 0.2  # of `data`'s scenarios held out for validation (at least one) when `val` is empty
    replay: list[str] = field(default_factory=list)  # base data mixed in, so the base is not forgotten
    replay_fraction: float = 0.0  # replay frames = this x the new training frames (drawn at random, seeded)
    base: str = "yolov8n.yaml"  # a .pt detector (fine-tune), a model YAML (from scratch) or models:/NAME/VERSION
    epochs: int = 10
    imgsz: int = 320
    batch: int = 16
    seed: int = 0
    freeze: int = 0  # the first N layers kept frozen (ultralytics' `freeze`)
    # A .pt base's BatchNorms calibrated on N of the training's frames (new and replay, drawn with `seed`) before
    # fine-tuning, eval outputs unchanged (garage_exp/train/calibrate.py): needed for a base whose BatchNorms were
    # folded away (the COCO yolo11n rebuilt from INT8). 0: no calibration.
    bn_calibrate: int = 0
    # ultralytics' `auto` picks AdamW at lr 0.002 x 5 / (4 + classes) for short trainings: 0.00012 for COCO's 80
    # classes, too slow to learn from scratch in a few hundred iterations. Name one (SGD, AdamW, ...) to set lr0.
    optimizer: str = "auto"
    lr0: Optional[float] = None  # the initial learning rate (with a named optimizer); None: ultralytics' default
    # Where the biases' learning rate starts its warm-up (ultralytics: 0.1, falling to lr0 over the warm-up; its own
    # `auto` optimizer starts at 0). A short fine-tuning of a pretrained detector is all warm-up: 0.1 with AdamW
    # moves every bias by about 0.1 a step. None: ultralytics' default.
    warmup_bias_lr: Optional[float] = None
    device: str = "auto"  # auto: the first GPU when there is one, else the CPU; or cpu, 0, cuda:0, ...
    workers: int = 2  # dataloader workers
    register: bool = True  # register the weights as a version of `registered_name`
    registered_name: str = REGISTERED_NAME
    study: str = ""  # the study that found the data (a tag of the run and the model version)
    name: str = ""  # the run's name; empty: from the base and the data
    tracking: TrackingConf = field(default_factory=lambda: TrackingConf(experiment="garage_train"))


def register() -> None:
    ConfigStore.instance().store(name="train_schema", node=TrainConf)
