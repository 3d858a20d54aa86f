"""Users' own detector functions, as `callable:user_detectors:NAME` entries in the tests (tests/test_entries.py).
The module is allowed by GARAGE_EXP_MODIFIER_MODULES=user_detectors and found through PYTHONPATH=tests."""

import numpy as np

from garage_exp.perception.detect import Detections
from garage_exp.scene.lenses import Lens

SEEN: list = []  # (frame shape, intrinsics) of each call, for tests that call it in their own process


def centre_box(frames, intrinsics):
    """One "car" in the middle of each frame, scored by its brightness there; checks the documented contract:
    a list of RGB uint8 frames and one camera lens (scene.lenses.Lens, or None) per frame."""
    assert isinstance(frames, list) and len(intrinsics) == len(frames)
    out = []
    for rgb, cam in zip(frames, intrinsics):
        assert rgb.dtype == np.uint8 and rgb.ndim == 3 and rgb.shape[2] == 3
        assert cam is None or (isinstance(cam, Lens) and (cam.height, cam.width) == rgb.shape[:2])
        SEEN.append((rgb.shape, cam))
        h, w = rgb.shape[:2]
        box = [w * 0.3, h * 0.3, w * 0.7, h * 0.7]
        score = float(rgb[int(h * 0.3):int(h * 0.7), int(w * 0.3):int(w * 0.7)].mean()) / 255.0
        out.append(Detections(np.array([box], np.float32), np.array([score], np.float32), ["car"]))
    return out


centre_box.classes = ["car", "person"]


def german_names(frames, intrinsics):
    """A model with its own class names: "Auto" for a car, "Fussgaenger" for a person."""
    out = []
    for rgb in frames:
        h, w = rgb.shape[:2]
        out.append(Detections(np.array([[10, 10, w / 2, h / 2], [w / 2, h / 2, w - 1, h - 1]], np.float32),
                              np.array([0.8, 0.6], np.float32), ["Auto", "Fussgaenger"]))
    return out


german_names.classes = ["Auto", "Fussgaenger", "Baum"]


def normalised(frames, intrinsics):
    """Boxes in 0-1 image fractions instead of pixels."""
    return [Detections(np.array([[0.1, 0.1, 0.5, 0.5]], np.float32), np.array([0.9], np.float32), ["car"])
            for _ in frames]


normalised.classes = ["car"]


def too_few(frames, intrinsics):
    """One result for a whole batch."""
    return centre_box(frames[:1], intrinsics[:1])


too_few.classes = ["car"]


def unnamed_walker(frames, intrinsics):
    """A "Pedestrian" box and no `classes` attribute: its names come from the config (detector.class_names), and it
    answers "Cyclist" on a white frame, a name it was not given."""
    out = []
    for rgb in frames:
        h, w = rgb.shape[:2]
        name = "Cyclist" if rgb.min() == 255 else "Pedestrian"
        out.append(Detections(np.array([[10, 10, w / 2, h / 2]], np.float32), np.array([0.7], np.float32), [name]))
    return out
