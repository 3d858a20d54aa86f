import importlib.util
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import require, schema_node

from garage_exp.perception.detect import Detections, GTBox, iou, score_target
from garage_exp.perception.detect import entries as entry_kinds
from garage_exp.perception.detect import ultralytics_entry
from garage_exp.perception.detect import detector as detector_module
from garage_exp.core import offline
from garage_exp.core.errors import GarageError

DEFAULT_MODELS = ("yolo11n_int8_openvino_model", "yolov8n_int8_openvino_model", "yolo26n_int8_openvino_model")
BUS_BOX = (10.0, 230.0, 805.0, 760.0)  # the bus in ultralytics' bus.jpg (810x1080), by hand


def dets(model: str, *rows: tuple) -> Detections:
    """Synthetic detections: rows of (x1, y1, x2, y2, conf, class)."""
    return Detections(np.array([r[:4] for r in rows], np.float32).reshape(-1, 4),
                      np.array([r[4] for r in rows], np.float32), [r[5] for r in rows], model)


# --- IoU and matching, no model -------------------------------------------------------------------------------

def test_iou():
    assert iou((0, 0, 10, 10), (0, 0, 10, 10)) == pytest.approx(1.0)
    assert iou((0, 0, 10, 10), (20, 20, 30, 30)) == 0.0
    assert iou((0, 0, 10, 10), (5, 0, 15, 10)) == pytest.approx(50 / 150)
    assert iou((0, 0, 10, 10), (2, 2, 4, 4)) == pytest.approx(4 / 100)
    assert iou((0, 0, 0, 10), (0, 0, 0, 10)) == 0.0  # empty boxes never match


def test_score_takes_the_best_vehicle_match_per_model_and_averages():
    target = GTBox((100, 100, 200, 200), (100, 100, 200, 200))
    models = [
        dets("a", (100, 100, 200, 200, 0.6, "car"), (102, 100, 200, 200, 0.9, "truck"), (0, 0, 50, 50, 0.99, "car")),
        dets("b", (100, 100, 200, 200, 0.95, "person")),  # right place, wrong class: a miss
        dets("c", (150, 150, 250, 250, 0.8, "car")),  # IoU 1/7: a miss
    ]
    score = score_target(models, target, [target])
    assert score.per_model == pytest.approx([0.9, 0.0, 0.0])
    assert score.matched == [1, -1, -1]
    assert score.composite == pytest.approx(0.3)
    assert not score.detected
    assert score_target(models, target, [target], threshold=0.29).detected
    assert score_target(models, target, [target], iou_threshold=0.1).per_model[2] == pytest.approx(0.8)


def test_no_detections_and_target_out_of_view_score_zero():
    target = GTBox((0, 0, 10, 10))
    empty = [dets("a"), dets("b")]
    assert score_target(empty, target).per_model == [0.0, 0.0]
    out_of_view = score_target([dets("a", (0, 0, 10, 10, 0.9, "car"))], None)
    assert out_of_view.composite == 0.0 and not out_of_view.detected
    assert out_of_view.false_positives == 1  # with no ground truth at all, the car box matches nothing


def test_match_modes_full_visible_either():
    # A car two-thirds hidden behind a pillar: the detector boxes the visible third only (IoU 1/3 with full).
    target = SimpleNamespace(name="t", full_box=(0, 0, 300, 100), visible_box=(0, 0, 100, 100))
    models = [dets("a", (0, 0, 100, 100, 0.7, "car"))]
    assert score_target(models, target, match="full").composite == 0.0
    assert score_target(models, target, match="visible").composite == pytest.approx(0.7)
    assert score_target(models, target, match="either").composite == pytest.approx(0.7)
    whole = [dets("a", (0, 0, 300, 100, 0.8, "car"))]
    assert score_target(whole, target, match="full").composite == pytest.approx(0.8)
    assert score_target(whole, target, match="visible").composite == 0.0
    hidden = SimpleNamespace(full_box=(0, 0, 300, 100), visible_box=None)  # in view but fully occluded
    assert score_target(models, hidden, match="visible").composite == 0.0


def test_bare_box_target():
    assert score_target([dets("a", (0, 0, 10, 10, 0.5, "bus"))], (0, 0, 10, 10)).composite == pytest.approx(0.5)


def test_false_positives():
    target = GTBox((0, 0, 100, 100), (0, 0, 100, 100))
    parked = GTBox((300, 0, 400, 100), (300, 0, 350, 100))  # half hidden
    models = [dets(
        "a",
        (0, 0, 100, 100, 0.9, "car"),  # the target
        (300, 0, 350, 100, 0.8, "car"),  # the parked car's visible part: real, whatever the match mode
        (600, 0, 700, 100, 0.7, "truck"),  # no vehicle there
        (600, 0, 700, 100, 0.1, "car"),  # too weak to count
        (10, 10, 50, 90, 0.6, "person"),  # a non-vehicle class
    )]
    score = score_target(models, target, [target, parked], match="full")
    assert score.false_positives == 2 and score.false_positives_per_model == [2]
    assert score_target(models, target, [target, parked], fp_conf=0.05).false_positives == 3
    assert score_target(models, target, [target], fp_conf=0.05).false_positives == 4
    # The target counts as ground truth even when the caller leaves it out of `truth`.
    assert score_target(models, target, [parked]).false_positives == 2


def test_custom_vehicle_classes():
    target = GTBox((0, 0, 10, 10))
    models = [dets("a", (0, 0, 10, 10, 0.9, "motorcycle"))]
    assert score_target(models, target).composite == 0.0
    assert score_target(models, target, classes=("car", "motorcycle")).composite == pytest.approx(0.9)


@pytest.mark.parametrize("kwargs, where", [
    ({"match": "centre"}, "detector.match"), ({"iou_threshold": 0.0}, "detector.iou"),
    ({"threshold": 2.0}, "detector.threshold")])
def test_bad_matching_settings(kwargs, where):
    with pytest.raises(GarageError) as err:
        score_target([], None, **kwargs)
    assert err.value.where == where


# --- model paths, no model loaded --------------------------------------------------------------------------------

@pytest.fixture
def no_loading(monkeypatch):
    """Fail the test if anything would load (or download) a model."""
    def refuse(*args, **kwargs):
        raise AssertionError("a model was loaded")
    monkeypatch.setattr(ultralytics_entry, "load_model", refuse)


def test_missing_model_path_names_it(tmp_path, no_loading):
    missing = tmp_path / "nothing_openvino_model"
    with pytest.raises(GarageError) as err:
        detector_module.Detector([missing])
    assert err.value.where == f"detector.models {missing}"


def test_bare_weights_name_is_refused_not_downloaded(tmp_path, monkeypatch, no_loading):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(GarageError, match="GitHub"):
        detector_module.Detector(["yolo11n.pt"])
    assert not (tmp_path / "yolo11n.pt").exists()


def test_one_bad_path_fails_before_any_loading(tmp_path, no_loading):
    good = tmp_path / "good_openvino_model"
    good.mkdir()
    (good / "good.xml").write_text("<net/>")
    with pytest.raises(GarageError) as err:
        detector_module.Detector([good, tmp_path / "missing.pt"])
    assert err.value.where.endswith("missing.pt")


def test_entry_kind_dispatch(tmp_path, no_loading):
    """The kind of an entry is decided from its string or file, without loading it."""
    ov = tmp_path / "m_openvino_model"
    ov.mkdir()
    entry = entry_kinds.make_entry(str(ov), detector_module.EntrySettings())
    with pytest.raises(GarageError, match="no .xml"):
        entry.check()
    (ov / "m.xml").write_text("<net/>")
    assert entry_kinds.kind_of(str(ov)).name == "ultralytics"
    for suffix in (".pt", ".engine", ".torchscript"):
        (tmp_path / f"m{suffix}").write_bytes(b"")
        assert entry_kinds.kind_of(str(tmp_path / f"m{suffix}")).name == "ultralytics"
    plain = tmp_path / "weights"
    plain.mkdir()
    with pytest.raises(GarageError, match="_openvino_model"):
        entry_kinds.kind_of(str(plain))
    onnx = tmp_path / "m.onnx"
    onnx.write_bytes(b"")
    assert entry_kinds.kind_of(str(onnx)).name == "onnx"  # not an ultralytics export: onnxruntime's
    other = tmp_path / "m.tflite"
    other.write_bytes(b"")
    with pytest.raises(GarageError, match="unsupported model file"):
        entry_kinds.kind_of(str(other))
    assert entry_kinds.kind_of("callable:pkg.mod:fn").name == "callable"
    assert entry_kinds.kind_of("torchvision:fcos_resnet50_fpn:x.pth").name == "torchvision"


def test_model_labels_are_short_and_unique():
    assert ultralytics_entry.model_label(Path("/x/yolo11n_int8_openvino_model")) == "yolo11n_int8"
    assert ultralytics_entry.model_label(Path("/x/best.pt")) == "best"
    assert detector_module.unique(["a", "b", "a"]) == ["a", "b", "a_2"]


def test_iou_of_degenerate_and_integer_boxes():
    """Boxes with no area (or inverted) overlap nothing; integer boxes divide as floats."""
    from garage_exp.perception.detect.matching import iou_many

    assert iou((0, 0, 3, 3), (1, 1, 2, 2)) == pytest.approx(1 / 9)  # ints: not floor division
    assert iou((5, 5, 5, 5), (5, 5, 5, 5)) == 0.0  # both empty: no union, 0 not NaN
    assert iou((10, 0, 0, 10), (0, 0, 10, 10)) == 0.0  # inverted width: no area, no overlap
    assert iou((0, 10, 10, 0), (0, 0, 10, 10)) == 0.0
    assert iou((0, 0, 10, 10), (10, 0, 0, 10)) == 0.0
    assert iou((0, 0, 10, 10), (0, 10, 10, 0)) == 0.0
    assert iou((0, 0, 0.5, 0.5), (0, 0, 0.5, 0.5)) == pytest.approx(1.0)  # sub-pixel boxes still count
    assert iou((0, 0, 10, 0.5), (0, 0, 10, 0.5)) == pytest.approx(1.0)
    assert iou((0, 0, 0.5, 10), (0, 0, 0.5, 10)) == pytest.approx(1.0)
    many = iou_many(np.array([[0, 0, 10, 10], [0, 0, 5, 10]]), (0, 0, 10, 10))
    assert many.dtype == float and many.shape == (2,) and many[1] == pytest.approx(0.5)
    assert iou_many(np.array([[0, 0, 10, 10]]), None).tolist() == [0.0]
    assert iou_many(np.zeros((0, 4)), (0, 0, 1, 1)).shape == (0,)


def test_score_target_boundaries_and_messages():
    target = GTBox((0, 0, 10, 10), (0, 0, 5, 10))
    half = dets("m", (0, 0, 5, 10, 0.5, "car"))  # IoU 0.5 with the full box: exactly the threshold
    score = score_target([half], target, match="full", iou_threshold=0.5, threshold=0.5)
    assert score.per_model == [0.5] and score.detected  # IoU >= threshold matches, composite >= threshold
    assert score_target([half], target, match="full", iou_threshold=1.0).per_model == [0.0]
    assert score_target([half], target, match="either", iou_threshold=1.0).per_model == [0.5]  # the visible box
    assert not score_target([half], target, threshold=0.51).detected
    assert score_target([half], target, threshold=1.0).detected is False
    assert score_target([half], target, threshold=0.0).detected
    empty = score_target([], target)
    assert empty.per_model == [] and empty.composite == 0.0 and not empty.detected
    ints = dets("m", (0, 0, 10, 10, 1, "car"))
    assert score_target([ints], target).per_model == [1.0]
    for kwargs, where, message in (({"match": "box"}, "detector.match", "unknown match 'box' (full | visible | either)"),
                                   ({"iou_threshold": 0.0}, "detector.iou", "iou 0.0 is outside (0, 1]"),
                                   ({"iou_threshold": 1.5}, "detector.iou", "iou 1.5 is outside (0, 1]"),
                                   ({"threshold": -0.1}, "detector.threshold", "-0.1 is outside 0-1"),
                                   ({"threshold": 1.1}, "detector.threshold", "1.1 is outside 0-1")):
        with pytest.raises(GarageError) as err:
            score_target([half], target, **kwargs)
        assert err.value.where == where and message in str(err.value)


def test_target_out_of_view_scores_zero_and_counts_no_target_hit():
    car = dets("m", (0, 0, 10, 10, 0.9, "car"))
    score = score_target([car], None, truth=[])
    assert score.per_model == [0.0] and score.matched == [-1] and score.false_positives == 1
    other = GTBox((0, 0, 10, 10))
    assert score_target([car], None, truth=[other]).false_positives == 0


# --- offline setup -----------------------------------------------------------------------------------------------

def test_fonts_are_installed_so_plots_never_download(tmp_path):
    offline._install_fonts(tmp_path)
    for name in offline.FONT_NAMES:
        assert (tmp_path / name).stat().st_size > 100_000


def test_openvino_telemetry_opt_out(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    # setenv first so that monkeypatch restores "CI unset" afterwards: the opt-in case below sets CI=true, which
    # must not leak into later tests (the conftest reads CI to make skips errors).
    monkeypatch.setenv("CI", "unset-by-this-test")
    monkeypatch.delenv("CI")
    offline._opt_out_of_openvino_telemetry()
    assert (tmp_path / "intel" / "openvino_telemetry").read_text() == "0"
    assert "CI" not in os.environ
    # A consent file that opts in: this process still sends nothing (openvino skips telemetry when CI=true).
    (tmp_path / "intel" / "openvino_telemetry").write_text("1")
    offline._opt_out_of_openvino_telemetry()
    assert os.environ["CI"] == "true"


# --- real models -------------------------------------------------------------------------------------------------

def default_models() -> list[Path]:
    """The default detector's models, found as the product finds them (a skip only where they are missing)."""
    require("models")
    return [entry_kinds.resolve(name) for name in DEFAULT_MODELS]


def bus_image() -> tuple[Path, np.ndarray]:
    from PIL import Image

    path = Path(importlib.util.find_spec("ultralytics").origin).parent / "assets" / "bus.jpg"
    return path, np.array(Image.open(path).convert("RGB"))


@pytest.fixture(scope="module")
def detector():
    return detector_module.Detector(default_models())


@pytest.mark.detect
def test_default_models_find_the_bus(detector):
    _, rgb = bus_image()
    found = detector.detect([rgb])[0]
    assert [d.model for d in found] == ["yolo11n_int8", "yolov8n_int8", "yolo26n_int8"]
    bus = GTBox(BUS_BOX, BUS_BOX)
    score = score_target(found, bus, [bus])
    assert min(score.per_model) > 0.5, score.per_model
    assert score.detected
    for model, index in zip(found, score.matched):
        assert model.classes[index] == "bus"
    # The four people are not vehicles: every model reports some of them as false positives.
    assert all(n >= 3 for n in score.false_positives_per_model), score.false_positives_per_model


@pytest.mark.detect
def test_rgb_frames_match_ultralytics_own_file_reading(detector):
    """ultralytics reads files with OpenCV (BGR); our RGB arrays must give the very same detections."""
    path, rgb = bus_image()
    ours = detector.detect([rgb])[0][0]
    theirs = detector.entries[0]._model.predict(str(path), conf=detector.conf, imgsz=detector.imgsz,
                                                verbose=False)[0]
    assert np.allclose(ours.boxes, theirs.boxes.xyxy.cpu().numpy(), atol=0.5)
    assert np.allclose(ours.scores, theirs.boxes.conf.cpu().numpy(), atol=1e-4)
    swapped = detector.detect([np.ascontiguousarray(rgb[..., ::-1])])[0][0]
    assert not np.allclose(swapped.scores[:3], ours.scores[:3], atol=1e-4)


@pytest.mark.detect
def test_models_are_loaded_once_per_process(detector):
    again = detector_module.Detector(detector.models)
    again.check()
    assert all(a._model is b._model for a, b in zip(again.entries, detector.entries))


@pytest.mark.detect
def test_pt_weights_load_through_the_same_path(tmp_path):
    """No .pt weights can be downloaded here, so build an untrained yolo11n from ultralytics' bundled yaml,
    save it as .pt and load that: the .pt branch of the loader works end to end, offline."""
    offline.prepare_offline()
    from ultralytics import YOLO
    from ultralytics.utils import ROOT, YAML

    model = YOLO("yolo11n.yaml", task="detect")
    model.model.names = YAML.load(ROOT / "cfg" / "datasets" / "coco.yaml")["names"]
    weights = tmp_path / "untrained.pt"
    model.save(weights)
    detector = detector_module.Detector([weights], conf=0.0, imgsz=320)
    found = detector.detect([np.zeros((240, 320, 3), np.uint8)])[0]
    assert detector.names == ["untrained"] and found[0].model == "untrained"
    assert found[0].boxes.shape == (len(found[0].classes), 4) and len(found[0].classes) > 0


@pytest.mark.detect
def test_from_config(detector):
    from garage_exp.perception.schema import DetectorConf

    conf = schema_node(DetectorConf, {"models": list(detector.models), "registry": None})
    made = detector_module.build_detector(conf)
    assert made.names == detector.names and made.classes == ("car", "truck", "bus") and made.conf == 0.05
