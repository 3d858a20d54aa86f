"""Multi-camera rigs (issue 11): every camera that sees the target is scored, and the job says which camera saw
it first and best; the fisheye4 rig runs as a job."""

from __future__ import annotations

import math

import pandas as pd
import pytest
from conftest import run_app

from garage_exp.results.table import camera_line, per_camera, summarise
from garage_exp.results.table import summarise as frame_summary


def frames(rows):
    return pd.DataFrame([{"shot": s, "label": label, "camera": cam, "visible_fraction": vis, "composite": conf,
                          "false_positives": 0} for s, label, cam, vis, conf in rows])


def test_each_camera_is_scored_where_it_sees_the_target():
    table = frames([
        (0, "black", "front", 0.5, 0.1), (0, "black", "left", 0.0, 0.0),
        (1, "black", "front", 0.6, 0.3), (1, "black", "left", 0.4, 0.6),  # left detects first (shot 1)
        (2, "black", "front", 0.9, 0.8), (2, "black", "left", 0.5, 0.7),
        (3, "white", "front", 0.9, 0.9), (3, "white", "left", 0.0, 0.0),  # front alone in the second trajectory
    ])
    cams = per_camera(table, threshold=0.5).set_index("camera")
    assert cams.loc["front", "in_view"] == 4 and cams.loc["left", "in_view"] == 2
    assert cams.loc["left", "confidence_in_view"] == pytest.approx(0.65)  # frames out of view do not count
    assert cams.loc["front", "confidence_in_view"] == pytest.approx(0.525)
    assert cams.loc["left", "first"] == 1 and cams.loc["front", "first"] == 1
    assert cams.loc["left", "first_shot"] == 1 and cams.loc["front", "first_shot"] == 2
    assert camera_line(cams.reset_index()).startswith("first: front") and "best: left" in camera_line(
        cams.reset_index())
    summary = summarise(table, 0.5, primary="front")
    assert summary["camera.left.confidence_in_view"] == pytest.approx(0.65)
    assert summary["camera.front.recall_in_view"] == pytest.approx(0.5)
    never = per_camera(table.assign(composite=0.0), threshold=0.5)
    assert camera_line(never).startswith("never detected") and math.isnan(never.first_shot.iloc[0])


def test_a_rigs_headline_counts_and_scores_the_same_camera():
    """Issue 31, item 4: the headline counted the frames of all four cameras and scored the front one; it now
    counts the frames it scores (the primary camera's) and names that camera."""
    from garage_exp.results.summary import JobSummary
    from garage_exp.results.table import JobNames, one_line

    table = frames([(s, "black", cam, 0.5, 0.9 if cam == "rear" else 0.0)
                    for s in range(7) for cam in ("front", "rear", "left", "right")])
    cfg = JobNames("slots", "x", "x", "x")
    rig = ["front", "rear", "left", "right"]

    def summarise(*args, **kw):
        return JobSummary.of(frame_summary(*args, **kw))

    line = one_line(cfg, summarise(table, 0.5, primary="front"), rig, "front")
    assert ": front camera (the primary of 4; cameras.csv scores each), 7 frames, " in line
    assert line.endswith("recall 0.00, difficulty 1.000")
    # a case that names its camera (case.camera: rear, as cpra does) is headlined by that camera's frames
    named = one_line(cfg, summarise(table, 0.5, primary="rear"), rig, "rear")
    assert ": rear camera (the primary of 4; cameras.csv scores each), 7 frames, " in named
    assert named.endswith("recall 1.00, difficulty 0.100")
    single = one_line(cfg, summarise(table[table.camera == "rear"], 0.5, primary="rear"), ["rear"], "rear")
    assert single.endswith(": 7 frames, confidence mean 0.900 min 0.900, recall 1.00, difficulty 0.100")


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_the_fisheye4_rig_runs_a_job(tmp_path, mlflow_uri):
    r = run_app(["case=1", "case.motion.start=8.0", "case.motion.end=8.0", "palette.target_colours=[black]",
                 "renderer.save_frames=none", "camera=fisheye4", "camera.width=160", "camera.height=120",
                 "detector.models=[yolov8n_int8_openvino_model]", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    table = pd.read_csv(tmp_path / "run" / "frames.csv")
    assert list(table.camera) == ["front", "rear", "left", "right"]
    front = table.iloc[0]
    assert front.visible_fraction > 0 and 0 < front.off_axis < 95  # within the front lens's half field
    assert table.iloc[1].kitti == "out_of_view"  # the rear camera does not see it
    cams = pd.read_csv(tmp_path / "run" / "cameras.csv")
    assert set(cams.camera) == set(table.camera) and "cameras: " in r.stdout
    assert ": front camera (the primary of 4; cameras.csv scores each), 1 frames, " in r.stdout


def test_the_sweep_report_says_which_camera_saw_the_target_first_and_best():
    from garage_exp.report.tables import by_camera, markdown_table, pivot

    one = frames([(0, "black", "front", 0.5, 0.2), (0, "black", "left", 0.5, 0.7),
                  (1, "black", "front", 0.8, 0.9), (1, "black", "left", 0.0, 0.0)])
    table = pd.concat([one.assign(run_id="a"), one.assign(run_id="b", composite=one.composite / 2)])
    runs = pd.DataFrame({"run_id": ["a", "b"], "threshold": [0.5, 0.5], "factor.light": ["bright", "dim"]})
    conf, first = by_camera(table, runs, ["factor.light"])
    cell = pivot(conf)
    assert cell.loc["left", "light=bright"].startswith("0.700") and cell.loc["front", "light=dim"].startswith("0.275")
    assert first.set_index(["what", "levels"])["first"].to_dict() == {
        ("front", "light=bright"): 0, ("left", "light=bright"): 1, ("front", "light=dim"): 0,
        ("left", "light=dim"): 0}
    assert "left" in markdown_table(cell.reset_index())
    assert by_camera(table[table.camera == "front"], runs, ["factor.light"])[0].empty  # one camera: no section
