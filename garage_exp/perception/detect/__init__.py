"""Vehicle and person detection with several YOLO models and the target's score.

Importing this package is cheap: ultralytics (and torch, ~5 s) load only when a `Detector` is made.
"""

from garage_exp.perception.detect.detector import Detector, ModelDetections, load_model, model_format, resolve_model
from garage_exp.perception.detect.matching import (MATCH_MODES, PERSON_CLASSES, VEHICLE_CLASSES, GTBox, TargetScore,
                                                   iou, iou_many, score_target)
from garage_exp.core.offline import prepare_offline

__all__ = ["Detector", "ModelDetections", "load_model", "model_format", "resolve_model", "MATCH_MODES",
           "VEHICLE_CLASSES", "PERSON_CLASSES", "GTBox", "TargetScore", "iou", "iou_many", "score_target",
           "prepare_offline"]
