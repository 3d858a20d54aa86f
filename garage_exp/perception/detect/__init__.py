"""Vehicle and person detection: the detector interface (base.py), its entry kinds (a registry,
kinds.py, each kind registered beside its class; entries.py resolves an entry to its kind), the composite
every caller builds through one factory (detector.py), and the target's score (matching.py).

Importing this package is cheap: ultralytics, torch and onnxruntime load only when an entry is checked.
"""

from garage_exp.core.offline import prepare_offline
from garage_exp.perception.detect.base import Detections, Entry, EntrySettings
from garage_exp.perception.detect.detector import Detector, build_detector, make_detector
from garage_exp.perception.detect.entries import resolve
from garage_exp.perception.detect.kinds import EntryKind, register_entry_kind
from garage_exp.perception.detect.matching import (MATCH_MODES, PERSON_CLASSES, VEHICLE_CLASSES, GTBox, Scoring,
                                                   TargetScore, iou, iou_many, score_target)

__all__ = ["Detections", "Entry", "EntrySettings", "Detector", "build_detector",
           "make_detector", "EntryKind", "register_entry_kind", "resolve", "MATCH_MODES", "VEHICLE_CLASSES", "PERSON_CLASSES",
           "GTBox", "Scoring", "TargetScore", "iou", "iou_many", "score_target", "prepare_offline"]
