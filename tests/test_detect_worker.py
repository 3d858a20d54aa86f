"""The detector child process and the overlapped frame loop: same detections, same order, errors as before."""

import numpy as np
import pytest

from garage_exp.perception.detect import worker
from garage_exp.perception.detect.detector import Detector
from garage_exp.core.errors import GarageError
from garage_exp.run.pipeline import overlapped


class Recorder:
    """A stand-in detector that logs calls: the pipeline must submit frame k+1 before reading frame k."""

    def __init__(self):
        self.calls, self.queue = [], []

    def submit(self, rgb, intrinsics=None):
        self.calls.append(("submit", int(rgb[0, 0, 0])))
        self.queue.append(int(rgb[0, 0, 0]))

    def result(self):
        k = self.queue.pop(0)
        self.calls.append(("result", k))
        return [k]


class Item:
    def __init__(self, k):
        self.rgb = np.full((2, 2, 3), k, np.uint8)
        self.camera = "front"


def test_overlapped_keeps_frame_order_and_submits_one_ahead():
    rec = Recorder()
    out = [(item.rgb[0, 0, 0], dets[0]) for item, dets in overlapped((Item(k) for k in range(4)), rec, {})]
    assert out == [(k, k) for k in range(4)]
    assert rec.calls == [("submit", 0), ("submit", 1), ("result", 0), ("submit", 2), ("result", 1),
                         ("submit", 3), ("result", 2), ("result", 3)]


def test_serial_fallback_is_chosen_by_the_environment(monkeypatch):
    monkeypatch.setenv("GARAGE_EXP_DETECT_PROCESS", "0")
    assert not worker.use_process()
    monkeypatch.setenv("GARAGE_EXP_DETECT_PROCESS", "1")
    assert worker.use_process()
    monkeypatch.setenv("GARAGE_EXP_OV_THREADS", "many")
    with pytest.raises(GarageError, match="GARAGE_EXP_OV_THREADS"):
        worker.configured_threads()


def test_a_bad_model_path_fails_in_the_parent_before_any_child(tmp_path):
    with pytest.raises(GarageError, match="model not found"):
        Detector([tmp_path / "nothing_openvino_model"], classes=("car",))


@pytest.fixture(scope="module")
def spec():
    from test_detect import default_models

    return Detector(default_models(), classes=("car", "truck", "bus"), conf=0.05, imgsz=640, device="cpu")


@pytest.fixture(scope="module")
def children():
    """The module's detector child: started once (a new interpreter importing torch and OpenVINO), shared by the
    tests that talk to it; a test that closes it leaves the next one a new child."""
    held = []
    yield held
    for child in held:
        child.close()


@pytest.fixture
def child(children):
    if not children or not children[-1].alive():
        children.append(worker.DetectorProcess(threads=1))
    return children[-1]


@pytest.mark.detect
def test_child_detections_equal_in_process_ones(spec, child):
    from test_detect import bus_image

    _, rgb = bus_image()
    frames = [rgb, np.zeros((480, 640, 3), np.uint8), np.ascontiguousarray(rgb[::2, ::2])]
    here = spec
    child.load(spec)
    assert child.names == here.names
    for frame in frames:
        child.submit(frame)
    for frame in frames:
        theirs, ours = child.result(), here.detect([frame])[0]
        for a, b in zip(theirs, ours):
            assert a.model == b.model and a.classes == b.classes
            np.testing.assert_allclose(a.scores, b.scores, atol=1e-6)
            np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-3)


@pytest.mark.detect
def test_child_errors_are_garage_errors_and_the_child_survives(spec, child):
    """The child that answered the test above (when it ran first): a refused spec, then the good one again."""
    try:
        from dataclasses import replace

        child.load(replace(spec, classes=("spaceship",)))
        with pytest.raises(GarageError, match="spaceship"):
            child.submit(np.zeros((64, 64, 3), np.uint8))
        child.load(spec)
        child.submit(np.zeros((64, 64, 3), np.uint8))
        child.drain()  # an unread answer (a failed job) is dropped, not read by the next job
        child.submit(np.zeros((64, 64, 3), np.uint8))
        assert [d.model for d in child.result()] == child.names
        with pytest.raises(RuntimeError, match="no detection pending"):
            child.result()
    finally:
        child.close()
    assert not child.alive()


def test_a_render_failure_keeps_the_frame_already_sent():
    def frames():
        yield Item(0)
        yield Item(1)
        raise GarageError("boom", "renderer")

    rec, got = Recorder(), []
    with pytest.raises(GarageError, match="boom"):
        for item, dets in overlapped(frames(), rec, {}):
            got.append(dets[0])
    assert got == [0, 1]
