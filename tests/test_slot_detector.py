"""The slot detectors (garage_exp/slots/detector.py) on synthetic bird's-eye views drawn with OpenCV
(garage_exp/slots/synthetic.py: grey floor with noise, white bay lines 0.15 m wide, a row of four
perpendicular bays, one holding a dark car): no rendering."""

import math
import textwrap
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import compose_cfg, schema_node
from omegaconf import OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.slots.schema import SlotDetectorConf, SlotLinesConf, SlotMetricsConf
from garage_exp.slots.detector import check_slot_detector, check_slot_weights, from_pose, load
from garage_exp.slots.marks import SlotFrame
from garage_exp.slots.synthetic import bev_row
from garage_exp.slots.results import pool, score

SEEDS = range(4)


def node(**keys):
    return schema_node(SlotDetectorConf, keys)


def run_set(wear: float, entrance_line: bool) -> tuple[dict, list]:
    """The baseline over the synthetic set: pooled metrics, and (truth, found) per frame."""
    detect = load(node())
    frames, metrics = [], []
    for seed in SEEDS:
        image, truth = bev_row(seed, wear=wear, entrance_line=entrance_line)
        found = detect(image, truth.meters_per_pixel)
        frames.append((truth, found))
        metrics.append(score(truth, found, None, SlotMetricsConf()))
    return pool(metrics), frames


@pytest.fixture(scope="module")
def fresh():
    return {style: run_set(0.0, style) for style in (False, True)}


@pytest.mark.parametrize("entrance_line", [False, True], ids=["lines-only", "with-entrance-line"])
def test_lines_finds_the_marking_points_and_the_occupied_bay(fresh, entrance_line):
    pooled, frames = fresh[entrance_line]
    assert pooled["point_recall"] >= 0.9 and pooled["point_precision"] >= 0.9, pooled
    assert pooled["slot_recall"] >= 0.9, pooled
    assert pooled["point_error_m"] < 0.05
    for truth, found in frames:
        assert found.size == truth.size and found.meters_per_pixel == truth.meters_per_pixel
        occupied = [s for s in truth.slots if s.occupied]
        assert len(occupied) == 1
        a, b = (np.array(c) for c in occupied[0].corners[:2])
        hits = [s for s in found.slots
                if min(max(np.linalg.norm(np.array(s.corners[0]) - a), np.linalg.norm(np.array(s.corners[1]) - b)),
                       max(np.linalg.norm(np.array(s.corners[0]) - b), np.linalg.norm(np.array(s.corners[1]) - a)))
                < 0.17 / truth.meters_per_pixel]
        assert [s.occupied for s in hits] == [True]
    assert pooled["occupancy_accuracy"] == 1.0 and pooled["occupancy_n"] >= 0.9 * 3 * len(SEEDS)
    truth, found = frames[0]
    assert sorted(q.shape for q in found.points) == sorted(q.shape for q in truth.points) == ["L", "L", "T", "T", "T"]


def test_worn_lines_lower_recall(fresh):
    worn, _ = run_set(0.7, False)
    assert worn["point_recall"] < fresh[False][0]["point_recall"] - 0.2
    assert worn["slot_recall"] < fresh[False][0]["slot_recall"] - 0.2


def test_an_empty_floor_has_no_slots():
    image = np.full((200, 200, 3), 110, np.uint8)
    image += np.random.default_rng(0).integers(0, 8, image.shape, dtype=np.uint8)
    found = load(node())(image, 0.02)
    assert found.points == [] and found.slots == []


def test_the_callable_kind_loads_the_users_function(tmp_path, monkeypatch):
    (tmp_path / "my_slots.py").write_text(textwrap.dedent("""\
        from garage_exp.slots.marks import MarkingPoint, SlotFrame

        def detect(image, mpp):
            return SlotFrame([MarkingPoint(1.0, 2.0, 0.5)], [], mpp, (image.shape[1], image.shape[0]))

        def scaled(image, mpp, factor=1.0):
            return SlotFrame([MarkingPoint(1.0, 2.0, 0.5 * factor)], [], mpp, (image.shape[1], image.shape[0]))

        def wrong(image, mpp):
            return [(1.0, 2.0)]
        """))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("GARAGE_EXP_MODIFIER_MODULES", "my_slots")
    found = load(node(kind="callable", detect={"_target_": "my_slots.detect"}))(np.zeros((30, 40, 3), np.uint8), 0.05)
    assert isinstance(found, SlotFrame) and found.points[0].direction == 0.5 and found.size == (40, 30)
    # the node's other keys are the function's keyword arguments (built by core.plugins.build, as a partial)
    scaled = load(node(kind="callable", detect={"_target_": "my_slots.scaled", "factor": 3.0}))
    assert scaled(np.zeros((30, 40, 3), np.uint8), 0.05).points[0].direction == 1.5
    with pytest.raises(GarageError, match="slot_detector.detect._target_ my_slots.wrong: returned list, not a "):
        load(node(kind="callable", detect={"_target_": "my_slots.wrong"}))(np.zeros((30, 40, 3), np.uint8), 0.05)
    monkeypatch.delenv("GARAGE_EXP_MODIFIER_MODULES")
    with pytest.raises(GarageError, match="'my_slots.detect' is not a slot detector"):
        load(node(kind="callable", detect={"_target_": "my_slots.detect"}))


@pytest.mark.parametrize("keys, message", [
    ({"kind": "cnn"}, "slot_detector.kind: unknown kind 'cnn'"),
    ({"kind": "callable"}, "slot_detector.detect._target_: kind callable needs detect._target_"),
    ({"kind": "callable", "detect": {"_target_": ""}}, "kind callable needs detect._target_"),
    ({"kind": "callable", "detect": {"_target_": "os.system"}}, "'os.system' is not a slot detector"),
    ({"kind": "callable", "detect": {"_target_": "garage_exp.nowhere.detect"}}, "cannot import a slot detector"),
    # the old form is refused with the new one
    ({"kind": "callable", "target": "my_slots:detect"},
     "slot_detector.target: slot_detector.target is gone: name the function as "
     "slot_detector.detect._target_=my_slots.detect"),
    ({"kind": "pose", "model": "x.pt", "keypoints": "edges"}, "slot_detector.keypoints: unknown keypoints 'edges'"),
    ({"lines": {"bay_width": [3.2, 2.2]}}, "slot_detector.lines.bay_width: .* is not a range"),
    ({"lines": {"occupied_fraction": 1.5}}, "slot_detector.lines.occupied_fraction: 1.5 is outside"),
    ({"metrics": {"point_tolerance_m": 0.0}}, "slot_detector.metrics.point_tolerance_m"),
    ({"metrics": {"angle_tolerance_deg": 200}}, "slot_detector.metrics.angle_tolerance_deg"),
])
def test_bad_config_is_one_garage_error(keys, message):
    with pytest.raises(GarageError, match=message):
        check_slot_detector(node(**keys))


@pytest.mark.parametrize("model", ["", "/nonexistent/slots.pt", "slots.onnx"])
def test_a_pose_model_that_is_not_there_fails_before_loading(model, tmp_path):
    (tmp_path / "slots.onnx").write_bytes(b"x")
    conf = node(kind="pose", model=str(tmp_path / model) if model.endswith("onnx") else model)
    check_slot_detector(conf)  # values are fine: a dry run passes
    with pytest.raises(GarageError, match="slot_detector.model: .* is not an ultralytics pose model file"):
        check_slot_weights(conf)
    with pytest.raises(GarageError, match="is not an ultralytics pose model file"):
        load(conf)


def test_the_composed_config_has_the_lines_baseline_and_its_levels_check():
    cfg = compose_cfg()
    assert cfg.slot_detector.kind == "lines" and list(cfg.slot_detector.lines.bay_width) == [2.2, 3.2]
    for key, schema in (("lines", SlotLinesConf), ("metrics", SlotMetricsConf)):  # the YAML says what the schema does
        assert OmegaConf.to_container(cfg.slot_detector[key]) == OmegaConf.to_container(OmegaConf.structured(schema))
    check_slot_detector(cfg.slot_detector)
    example = compose_cfg("slot_detector=callable").slot_detector  # the shipped example: the baseline, called
    image, truth = bev_row(0)
    assert load(example)(image, truth.meters_per_pixel) == load(cfg.slot_detector)(image, truth.meters_per_pixel)


class Tensor:
    """What ultralytics' Results hold (torch tensors): `.cpu().numpy()`."""

    def __init__(self, values):
        self.values = np.asarray(values, np.float32)

    def cpu(self):
        return self

    def numpy(self):
        return self.values


def results(keypoints, conf, cls, names):
    return SimpleNamespace(keypoints=SimpleNamespace(xy=Tensor(keypoints)),
                           boxes=SimpleNamespace(conf=Tensor(conf), cls=Tensor(cls)), names=names)


def test_pose_corners_become_slots_sharing_their_marking_points():
    depth = 265.0
    quads = [[(100, 200), (225, 200), (225, 200 + depth), (100, 200 + depth)],
             [(226, 201), (350, 200), (350, 200 + depth), (226, 201 + depth)]]
    out = from_pose(results(quads, [0.9, 0.6], [1, 0], {0: "free", 1: "occupied"}), "corners", 0.02, (500, 500),
                    SlotLinesConf())
    assert [(q.x, q.y) for q in out.points] == [(100, 200), (225, 200), (350, 200)]  # 225 and 226 are one point
    assert all(math.isclose(q.direction, math.pi / 2, abs_tol=1e-3) for q in out.points)
    assert [(s.p1, s.p2, s.occupied, s.score) for s in out.slots] == [(0, 1, True, pytest.approx(0.9)),
                                                                      (1, 2, False, pytest.approx(0.6))]
    assert out.points[1].score == pytest.approx(0.9)  # the shared point keeps its best score
    assert out.slots[0].corners[2] == (225.0, 465.0)
    unknown = from_pose(results(quads[:1], [0.9], [0], {0: "slot"}), "corners", 0.02, (500, 500), SlotLinesConf())
    assert unknown.slots[0].occupied is None


def test_pose_points_are_paired_into_slots_like_the_baseline():
    kpts = [[(x, 200), (x, 230)] for x in (100, 225, 350, 700)]  # 700: 6.5 m on, no bay between
    out = from_pose(results(kpts, [0.8] * 4, [0, 1, 1, 0], {0: "L", 1: "T"}), "points", 0.02, (800, 500),
                    SlotLinesConf())
    assert [q.shape for q in out.points] == ["L", "T", "T", "L"]
    assert sorted(tuple(sorted((s.p1, s.p2))) for s in out.slots) == [(0, 1), (1, 2)]
    assert all(s.corners[2][1] > 200 for s in out.slots)  # pushed back along the points' direction


def test_pose_with_too_few_keypoints_or_none_found():
    with pytest.raises(GarageError, match="gives 2 keypoints per object; keypoints=corners needs 4"):
        from_pose(results([[(1, 2), (3, 4)]], [0.5], [0], {}), "corners", 0.02, (50, 50), SlotLinesConf())
    empty = from_pose(results(np.zeros((0, 4, 2)), [], [], {}), "corners", 0.02, (50, 50), SlotLinesConf())
    assert empty.points == [] and empty.slots == []


def test_a_line_end_at_unseen_pixels_gives_no_point_and_an_unseen_slot_no_occupancy():
    image, truth = bev_row(0)
    hidden = truth.points[2]
    x, y = int(hidden.x), int(hidden.y)
    image[y - 40:y + 40, x - 40:x + 40] = 0  # no camera saw the floor around this entrance (0.8 m square)
    found = load(node())(image, truth.meters_per_pixel)
    m = score(truth, found, None, SlotMetricsConf())
    assert (m["point_tp"], m["point_fp"], m["point_fn"]) == (4, 0, 1)  # not a point at the black edge instead
    from garage_exp.slots.lines import occupancy

    seen = np.ones(image.shape[:2], bool)
    corners = truth.slots[0].corners
    assert occupancy(image, seen, corners, np.array([118.0, 114.0, 104.0]), SlotLinesConf()) is not None
    seen[:] = False
    assert occupancy(image, seen, corners, np.array([118.0, 114.0, 104.0]), SlotLinesConf()) is None


def test_the_pose_kind_runs_a_real_ultralytics_pose_model(tmp_path):
    """An untrained yolov8n-pose (built from the YAML ultralytics ships: no download) saved as a .pt: its real
    Results go through from_pose; a detection model is refused in one line."""
    from ultralytics import YOLO

    YOLO("yolov8n-pose.yaml").save(tmp_path / "slots.pt")
    YOLO("yolov8n.yaml").save(tmp_path / "boxes.pt")
    image, truth = bev_row(0, size=320)
    detect = load(node(kind="pose", model=str(tmp_path / "slots.pt"), conf=0.0, imgsz=160))
    found = detect(image, truth.meters_per_pixel)  # untrained: whatever it says, as marking points and slots
    assert found.size == (320, 320) and found.slots and all(0 <= s.p1 < len(found.points) for s in found.slots)
    with pytest.raises(GarageError, match="boxes.pt: a detect model, not a pose"):
        load(node(kind="pose", model=str(tmp_path / "boxes.pt")))
