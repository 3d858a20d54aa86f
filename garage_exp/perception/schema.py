"""The `sensor` and `detector` groups' schemas, beside the factories their `_target_` names (perception/sensor.py,
perception/detect/detector.py, which check them), registered as config nodes here (core/config_nodes.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from garage_exp.core.config_nodes import register_node


@dataclass
class SensorConf:
    """The camera sensor: `_target_` names the factory called with the other keys (name, kind, params)."""

    name: str = "ideal"
    _target_: str = "garage_exp.perception.sensor.make_sensor"
    kind: str = "ideal"  # ideal | noisy | camera
    params: dict[str, Any] = field(default_factory=dict)


@dataclass
class DetectorConf:
    """The detector under test: `_target_` names the factory of the composite detector, called with the other keys.
    Entries of `models`: perception.detect.entries (docs/perception.md)."""

    name: str = "coco3"
    _target_: str = "garage_exp.perception.detect.detector.make_detector"
    models: list[str] = field(default_factory=lambda: ["yolo11n_int8_openvino_model", "yolov8n_int8_openvino_model",
                                                         "yolo26n_int8_openvino_model"])
    classes: list[str] = field(default_factory=lambda: ["car", "truck", "bus"])  # a vehicle target's classes
    person_classes: list[str] = field(default_factory=lambda: ["person"])  # a pedestrian target's classes
    # A model's own class names -> vehicle | person, for models whose names are not COCO's ({Pedestrian: person}).
    class_map: dict[str, str] = field(default_factory=dict)
    # A model's class names by index, for models that cannot give their own (a stock KServe server, a function
    # without `classes`): its name (the frame table's conf_<name>) -> a list, or a YAML/JSON/text file of them.
    class_names: dict[str, Any] = field(default_factory=dict)
    conf: float = 0.05  # keep low detections: a miss scores 0, a weak hit its confidence
    iou: float = 0.5
    match: str = "full"  # full | visible | either
    threshold: float = 0.5  # composite confidence counted as detected
    imgsz: int = 640
    # The MLflow store that `models:/NAME/VERSION` entries are read from; None: $MLFLOW_TRACKING_URI, else
    # outputs/mlflow.db. By default the job's own store (tracking.uri), where `python -m garage_exp.train` registers.
    registry: Optional[str] = "${oc.select:tracking.uri,null}"
    # auto: .pt models on the first CUDA GPU when torch sees one, else the CPU; OpenVINO exports always on the CPU.
    # cpu | cuda (cuda without a CUDA GPU is refused). perception.detect.devices.pick_device.
    device: str = "auto"


register_node("sensor", SensorConf, group=True)
register_node("detector", DetectorConf, group=True)
