"""Users' detector functions that are wrong in the ways the corpus checks (tests/bad_inputs/cases.yaml)."""

import numpy as np

from garage_exp.perception.detect import Detections


def raises(frames, intrinsics):
    return [1 / 0 for _ in frames]


def plain_lists(frames, intrinsics):
    """[x1, y1, x2, y2, score, class] rows, as many detectors print them: not the documented Detections."""
    return [[[10.0, 10.0, 50.0, 40.0, 0.9, "car"]] for _ in frames]


def kitti_names(frames, intrinsics):
    """A model trained on KITTI's names: without a class map none of them is a vehicle or a person."""
    return [Detections(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), []) for _ in frames]


kitti_names.classes = ["Car", "Van", "Pedestrian", "Cyclist"]
