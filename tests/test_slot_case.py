"""`camera=fisheye4 case=slots` end to end (issue 25): two frames of the tiny plan at 320x240 write the BEV frames,
the slot truth and exports, and the slot metrics to MLflow. The slot detector here is a stand-in set by the test
(it finds the truth's first slot); the package's own detector is the `slot_detector` group's."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from conftest import run_app

from garage_exp.slots.marks import SlotFrame
from garage_exp.tracking import runs as tracking

SLOTS = ["plan=tiny", "camera=fisheye4", "case=slots", "case.motion.start=3.0", "case.motion.end=4.0",
         "case.motion.step=1.0", "camera.width=320", "camera.height=240", "palette.target_colours=[black]",
         "detector.models=[yolov8n_int8_openvino_model]"]


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """One job with a stand-in slot detector: it returns nothing, and the stand-in score counts the fair slots."""
    import garage_exp.slots.frames as run_slots

    tmp = tmp_path_factory.mktemp("slots")
    seen = []

    def detect(bev, meters_per_pixel):
        seen.append((bev.shape, meters_per_pixel))
        return SlotFrame([], [], meters_per_pixel, (bev.shape[1], bev.shape[0]))

    def score(truth, found, fair, conf):
        n = float(sum(fair))
        return {"point_recall": 0.0, "slot_recall": 0.0, "slot_fn": n, "slot_tp": 0.0}

    def pool(frames):
        return {"slot_recall": 0.0, "point_recall": 0.0, "fair": sum(f["slot_fn"] for f in frames)}

    patch = pytest.MonkeyPatch()
    patch.setattr(run_slots, "finder", lambda cfg: (detect, score, pool, None))
    try:
        r = run_app([*SLOTS, f"tracking.uri=sqlite:///{tmp / 'mlflow.db'}"], tmp)
    finally:
        patch.undo()
    return r, tmp, seen


@pytest.mark.render
@pytest.mark.slow
def test_the_slot_case_writes_bev_frames_truth_and_metrics(job):
    r, tmp, seen = job
    assert r.returncode == 0, r.stderr[-3000:]
    out = tmp / "run"
    assert (out / "frames" / "0000_bev.png").exists() and (out / "frames" / "0001_bev.png").exists()
    assert seen == [((400, 600, 3), 0.03)] * 2  # the detector got each BEV frame once
    table = pd.read_csv(out / "slots.csv")
    assert list(table.shot) == [0, 1] and (table.slots >= 4).all() and (table.fair >= 1).all()
    truth = json.loads((out / "slots" / "truth" / "0000_bev.json").read_text())
    assert {s["bay"] for s in truth["slots"] if s["occupied"]} >= {"bay_2_0_0"}  # the case's car
    assert (out / "slots" / "coco_keypoints.json").exists() and (out / "slots" / "ps2" / "0001_bev.json").exists()
    mlc = tracking.client(f"sqlite:///{tmp / 'mlflow.db'}")
    exp = mlc.get_experiment_by_name("garage_exp")
    run = mlc.search_runs([exp.experiment_id])[0]
    metrics = run.data.metrics
    assert metrics["slot_frames"] == 2 and metrics["slot_recall"] == 0.0 and metrics["slot_truth_fair"] >= 1
    assert "slots: 2 BEV frames" in r.stdout
    arts = {a.path for a in mlc.list_artifacts(run.info.run_id)}
    assert {"slots", "slots.csv"} <= arts
