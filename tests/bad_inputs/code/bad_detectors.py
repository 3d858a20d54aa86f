"""Users' detector functions that are wrong in the ways the corpus checks (tests/bad_inputs/cases.yaml)."""

import numpy as np

from garage_exp.perception.detect import Detections


def raises(frames, intrinsics):
    return [1 / 0 for _ in frames]


raises.classes = ["car"]


def plain_lists(frames, intrinsics):
    """[x1, y1, x2, y2, score, class] rows, as many detectors print them: not the documented Detections."""
    return [[[10.0, 10.0, 50.0, 40.0, 0.9, "car"]] for _ in frames]


plain_lists.classes = ["car"]


def kitti_names(frames, intrinsics):
    """A model trained on KITTI's names: without a class map none of them is a vehicle or a person."""
    return [Detections(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), []) for _ in frames]


kitti_names.classes = ["Car", "Van", "Pedestrian", "Cyclist"]


def undeclared_kitti(frames, intrinsics):
    """KITTI's names without a `classes` attribute: the job could score none of them (issue 42: it scored 0 on
    every frame, exit 0)."""
    h, w = frames[0].shape[:2]
    box = np.array([[w * 0.3, h * 0.3, w * 0.7, h * 0.7]], np.float32)
    return [Detections(box, np.array([0.9], np.float32), ["Car"]) for _ in frames]
