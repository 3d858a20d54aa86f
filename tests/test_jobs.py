"""Levels that only a real job can prove: the surround rig, the low-light sensor, the busy palette and the
extra factors (pillar, wear) in one tiny job; the official .pt detector; case 2, run with the serial and with
the overlapped detection loop and the real detectors. Each job is one to three frames."""

from __future__ import annotations

import csv
import os

import pytest
import yaml
from conftest import ROOT, require, run_app
from omegaconf import OmegaConf

pytestmark = [pytest.mark.render, pytest.mark.detect, pytest.mark.slow]

ONE_FRAME = ["case=1", "case.motion.start=8.0", "case.motion.end=8.0", "palette.target_colours=[black]",
             "renderer.save_frames=none"]


def table(tmp_path):
    with open(tmp_path / "run" / "frames.csv") as fh:
        return list(csv.DictReader(fh))


def test_surround_rig_lowlight_sensor_busy_palette_and_extra_factors_in_one_job(tmp_path, mlflow_uri):
    require("vulkan", "vehicles", "models")
    r = run_app([*ONE_FRAME, "camera=surround", "sensor=lowlight", "palette=busy", "pillar=thick", "wear=worn",
                 "detector.models=[yolov8n_int8_openvino_model]", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    rows = table(tmp_path)
    rig = [c["name"] for c in yaml.safe_load((ROOT / "conf" / "camera" / "surround.yaml").read_text())["cameras"]]
    assert [x["camera"] for x in rows] == rig  # one shot, one row per camera of the rig
    assert len({(x["ego_x"], x["ego_y"], x["ego_yaw"]) for x in rows}) == 1
    front = next(x for x in rows if x["camera"] == "front")
    assert float(front["visible_fraction"]) > 0  # the target ahead is in the front camera's view
    used = OmegaConf.load(tmp_path / "run" / "config.yaml")
    assert used.sensor.name == "lowlight" and used.palette.parked_occupancy == 0.7
    assert used.modifiers.pillar.size == 0.9 and used.modifiers.wear.wear == 0.7


def test_official_pt_detector_runs_or_names_the_missing_weights(tmp_path):
    """detector=official_pt, both ways on every machine. Without the .pt weights in the models dir the job is
    refused with one line naming the missing file (exit 2): nothing written, nothing downloaded. With them
    (real ultralytics .pt files of the same three networks, built here from ultralytics' own model YAMLs with
    COCO's class names: untrained, but loaded and run exactly as the official weights) a one-frame job scores
    with the three .pt detectors and its frame table has a column for each."""
    require("vulkan", "vehicles")
    models = yaml.safe_load((ROOT / "conf" / "detector" / "official_pt.yaml").read_text())["models"]
    assert models and all(m.endswith(".pt") for m in models)
    empty, missing = tmp_path / "no_models", tmp_path / "missing"
    empty.mkdir()
    missing.mkdir()
    r = run_app([*ONE_FRAME, "detector=official_pt", f"tracking.uri=sqlite:///{missing}/mlflow.db"], missing,
                {"GARAGE_EXP_MODELS": str(empty)}, fresh_store=True)
    assert r.returncode == 2, r.stderr[-3000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert lines == [f"garage_exp: detector.models {empty / models[0]}: model not found"], r.stderr[-3000:]
    assert list(empty.iterdir()) == [] and list(missing.iterdir()) == []  # no store, no run, no download

    weights = tmp_path / "models"
    weights.mkdir()
    pt_weights(weights, [m[:-3] for m in models])
    r = run_app([*ONE_FRAME, "detector=official_pt", f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"], tmp_path,
                env={"GARAGE_EXP_MODELS": str(weights)})
    assert r.returncode == 0, r.stderr[-3000:]
    rows = table(tmp_path)
    assert len(rows) == 1
    confs = {c: rows[0][c] for c in rows[0] if c.startswith("conf_")}
    assert set(confs) == {f"conf_{m[:-3]}" for m in models}  # the .pt files' own names, not the OpenVINO exports'
    assert all(0.0 <= float(v) <= 1.0 for v in confs.values()), confs
    assert sorted(p.name for p in weights.iterdir()) == sorted(models)  # used where they were, nothing fetched


def pt_weights(folder, networks: list[str]) -> None:
    """Real ultralytics .pt checkpoints of these networks (e.g. yolo11n), without a download: each built from
    the model YAML ultralytics ships, with COCO's 80 class names, and saved untrained."""
    from garage_exp.perception.detect import prepare_offline

    prepare_offline()
    from ultralytics import YOLO
    from ultralytics.utils import ROOT as ULTRALYTICS, YAML

    names = YAML.load(ULTRALYTICS / "cfg" / "datasets" / "coco8.yaml")["names"]
    for network in networks:
        model = YOLO(f"{network}.yaml", task="detect")
        model.model.names = dict(names)
        model.save(folder / f"{network}.pt")


def test_case_2_runs_the_same_with_serial_and_overlapped_detection(tmp_path):
    """Case 2 as a user runs it, three frames (the passing car before, at and after the ego's axis), twice:
    GARAGE_EXP_DETECT_PROCESS=0 (detection in the job's process, after each frame) and =1 (a detector process
    overlapping the next frame's rendering) give the same frame table with the real detectors."""
    require("vulkan", "vehicles", "models")
    args = ["case=2", "case.motion.start=-1.0", "case.motion.end=1.0", "case.motion.step=1.0", "palette.target_colours=[black]",
            "renderer.save_frames=none"]
    dirs = {mode: tmp_path / mode for mode in ("0", "1")}
    for d in dirs.values():
        d.mkdir()
    done = {mode: run_app([*args, f"tracking.uri=sqlite:///{d}/mlflow.db"], d, {"GARAGE_EXP_DETECT_PROCESS": mode})
            for mode, d in dirs.items()}
    for mode, r in done.items():
        assert r.returncode == 0, (mode, r.stderr[-3000:])
    serial, overlapped = table(dirs["0"]), table(dirs["1"])
    assert [float(x["position"]) for x in serial] == [-1.0, 0.0, 1.0]
    assert {x["target"] for x in serial} == {"target_black"}
    assert min(float(x["visible_fraction"]) for x in serial) > 0.5  # the passing car is in view
    assert len(overlapped) == 3
    for a, b in zip(serial, overlapped):
        assert {k: v for k, v in a.items() if not k.startswith("conf_") and k != "composite"} == \
               {k: v for k, v in b.items() if not k.startswith("conf_") and k != "composite"}
        for k in [c for c in a if c.startswith("conf_")] + ["composite"]:
            assert float(a[k]) == pytest.approx(float(b[k]), abs=1e-6), k
    assert os.environ.get("GARAGE_EXP_DETECT_PROCESS") is None  # the modes were set for each command only
