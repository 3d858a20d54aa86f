"""The schema of `python -m garage_exp.verify`'s config (conf/verify.yaml), registered in Hydra's ConfigStore."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from hydra.core.config_store import ConfigStore

from garage_exp.perception.schema import DetectorConf
from garage_exp.tracking.schema import TrackingConf


@dataclass
class VerifyConf:
    """One check of a detector on a labelled image set."""

    data: str = ""  # a COCO JSON file, a YOLO data.yaml, or a folder holding one (a dataset, a job output, a suite)
    images: Optional[str] = None  # COCO: the folder its file_names are relative to (default: beside the file)
    split: str = "val"  # YOLO: the data.yaml's split scored (its `train` when it has none)
    # Label class names -> the detector's class names, for a set labelled in other words ({Car: car}).
    label_map: dict[str, str] = field(default_factory=dict)
    name: str = ""  # the run's name; empty: the detector on the data
    detector: DetectorConf = field(default_factory=DetectorConf)
    tracking: TrackingConf = field(default_factory=lambda: TrackingConf(experiment="garage_verify"))


def register() -> None:
    ConfigStore.instance().store(name="verify_schema", node=VerifyConf)
