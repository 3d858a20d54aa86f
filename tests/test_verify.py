"""`python -m garage_exp.verify` (issue 33, item 6): a detector scored on labelled real images, offline - the two
photos ultralytics ships (a bus and four people; two people and two ties) with labels made by hand here, as COCO
JSON and as YOLO data.yaml - and on a rendered dataset; its MLflow run and report; bad input in one line with
exit 2 and nothing written (more in the bad-input corpus)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import require, run_app, run_in_process

from garage_exp.results.photos import write_photos

YOLO = "yolo11n_int8_openvino_model"


def run_verify(args: list[str], cwd: Path, uri: str):
    from garage_exp.verify.app import cli

    return run_in_process([*args, f"tracking.uri={uri}", f"hydra.run.dir={cwd}/verify_run"], cwd, entry=cli)


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    require("models")
    return write_photos(tmp_path_factory.mktemp("photos"))


@pytest.mark.detect
def test_yolo11n_on_the_two_photos(photos, tmp_path):
    """COCO JSON: 7 scored objects (1 bus, 6 people), 2 ties not scored; yolo11n finds all but the cut-off person
    (0.44 < 0.5): recall 6/7; every labelled object is its best-ranked detection, so mAP50 is 1. The run is tracked,
    the report written with the caveat about synthetic results."""
    import mlflow

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    r = run_verify([f"data={photos / 'coco.json'}", "+label_map.pedestrian=person", f"detector.models=[{YOLO}]"],
                   tmp_path, uri)
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:])
    result = json.loads((tmp_path / "verify_run" / "result.json").read_text())
    m = result["metrics"]
    assert m["targets"] == 7 and m["targets/person"] == 6 and m["targets/vehicle"] == 1
    assert m["recall"] == pytest.approx(6 / 7) and m["recall/vehicle"] == 1.0
    assert m["map50"] == pytest.approx(1.0, abs=1e-6) and m["map50/yolo11n_int8"] == m["map50"]
    assert 0.75 < m["mean_confidence"] < 0.9
    assert set(k for k in m if k.startswith("confidence_by_height/")) == {"confidence_by_height/256px_up"}
    report = (tmp_path / "verify_run" / "report" / "report.md").read_text()
    assert "Synthetic results are only meaningful for a detector that is good on real images of the same classes" \
        in report
    assert "tie 2" in report and "| yolo11n_int8 | 0.857 |" in report and "Good on these real images" in report
    assert report.startswith("# Detector check on real images") and result["rendered"] is False
    # detector.models replaced coco3's models: the title names what was run, not the group (issue 42, item 7)
    assert report.splitlines()[0] == "# Detector check on real images: yolo11n_int8", report.splitlines()[0]
    client = mlflow.MlflowClient(tracking_uri=uri)
    (run,) = client.search_runs([client.get_experiment_by_name("garage_verify").experiment_id])
    assert run.info.status == "FINISHED" and run.data.metrics["recall"] == pytest.approx(6 / 7)
    assert run.info.run_name.startswith("yolo11n_int8 on ")
    assert {"report/report.md", "report/report.html", "report/objects.csv"} <= {
        a.path for a in client.list_artifacts(run.info.run_id, "report")}
    assert "recall 0.857, mAP50 1.000" in r.stdout


@pytest.mark.detect
def test_yolo_data_yaml_reads_as_the_coco_file(photos, tmp_path):
    """The same labels as a YOLO data.yaml score the same (up to the labels' 6 decimals)."""
    from garage_exp.verify.data import read_set

    coco = read_set(str(photos / "coco.json"), {"pedestrian": "person"})
    yolo = read_set(str(photos / "data.yaml"), {"pedestrian": "person"})
    assert [im.image.name for im in coco.images] == [im.image.name for im in yolo.images]
    for a, b in zip(coco.images, yolo.images):
        assert a.classes == b.classes and (abs(a.boxes - b.boxes) < 0.01).all()
    assert yolo.images[0].classes == ["bus", "person", "person", "person", "person"]
    elsewhere = tmp_path / "labels_only" / "val.json"  # a COCO file away from its images: `images` says where
    elsewhere.parent.mkdir()
    shutil.copyfile(photos / "coco.json", elsewhere)
    assert [im.image for im in read_set(str(elsewhere), {}, images=str(photos / "images")).images] == \
        [photos / "images" / "bus.jpg", photos / "images" / "zidane.jpg"]
    from garage_exp.core.errors import GarageError

    with pytest.raises(GarageError, match="image 'bus.jpg' not found in"):
        read_set(str(elsewhere), {})


def test_bad_data_is_one_line_and_writes_nothing(tmp_path):
    """A path that does not exist, a set with no labels, labels of no scored class: exit 2, one line naming the
    file, no run dir, no MLflow store."""
    (tmp_path / "empty" / "images").mkdir(parents=True)
    from PIL import Image

    Image.new("RGB", (8, 8)).save(tmp_path / "empty" / "images" / "a.png")
    (tmp_path / "empty" / "data.yaml").write_text("val: images\nnames: [car]\n")
    ties = {"images": [{"id": 1, "file_name": "a.png", "width": 8, "height": 8}], "categories": [{"id": 1, "name": "tie"}],
            "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "bbox": [1, 1, 3, 3], "iscrowd": 0}]}
    (tmp_path / "empty" / "ties.json").write_text(json.dumps(ties))
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    cases = {"data=/nonexistent/val.json": ["/nonexistent/val.json", "data: not found"],
             f"data={tmp_path / 'empty'}": ["data.yaml", "no labels on any of its 1 images"],
             f"data={tmp_path / 'empty' / 'ties.json'}": ["ties.json", "no labelled object of the scored classes",
                                                         "+label_map.tie=car"],
             "split=testing": ["split", "'testing' is not one of"]}
    for arg, said in cases.items():
        r = run_verify([arg, f"detector.models=[{YOLO}]"], tmp_path, uri)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("garage_exp.verify: "), r.stderr
        assert all(s in lines[0] for s in said), lines[0]
        assert not (tmp_path / "verify_run").exists() and not (tmp_path / "mlflow.db").exists()


def test_a_state_dict_of_another_shape_says_which_keys_in_one_line(tmp_path):
    """torch's message starts "Error(s) in loading state_dict for FasterRCNN:" and names the keys on the lines
    after; the refusal is one line with the keys, both shapes, and the class count the file was trained for
    (issue 42, item 7)."""
    import torch
    from torchvision.models import detection

    from garage_exp.core.errors import GarageError
    from garage_exp.perception.detect.base import EntrySettings
    from garage_exp.perception.detect.torchvision_entry import TorchvisionEntry

    arch = "fasterrcnn_mobilenet_v3_large_320_fpn"
    model = getattr(detection, arch)(weights=None, weights_backbone=None, num_classes=3)
    torch.save(model.state_dict(), tmp_path / "three.pth")  # a 3-class model saved without its names
    with pytest.raises(GarageError) as err:
        TorchvisionEntry(f"torchvision:{arch}:{tmp_path / 'three.pth'}", EntrySettings()).check()
    text = str(err.value)
    assert "\n" not in text and "Error(s) in loading" not in text, text
    assert f"does not fit {arch} with 91 classes: 4 of another shape (roi_heads.box_predictor.cls_score.weight: " \
           "[3, 1024] in the file, [91, 1024] here" in text, text
    assert "the file's model has 3 classes" in text, text
    torch.save(getattr(detection, "ssdlite320_mobilenet_v3_large")(weights=None, weights_backbone=None).state_dict(),
               tmp_path / "ssd.pth")  # another architecture's keys
    with pytest.raises(GarageError, match="keys missing .*; no key in common: a state dict of another architecture"):
        TorchvisionEntry(f"torchvision:{arch}:{tmp_path / 'ssd.pth'}", EntrySettings()).check()


@pytest.mark.render
@pytest.mark.slow
def test_verify_on_a_rendered_dataset(tmp_path, mlflow_uri):
    """A dataset=true job's output (YOLO data.yaml, COCO file) is a labelled set too: the same objects either way;
    the report says what synthetic results mean."""
    require("vulkan", "vehicles", "models")
    r = run_app(["case=1", "case.motion.start=12", "case.motion.end=11", "palette.target_colours=[black]",
                 "dataset=true", "renderer.save_frames=none", "camera.width=320", "camera.height=240",
                 f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    job = tmp_path / "run"
    got = {}
    for data in (job, job / "dataset" / "coco.json"):
        v = run_verify([f"data={data}", f"detector.models=[{YOLO}]"], tmp_path, mlflow_uri)
        assert v.returncode == 0, (v.stdout[-2000:], v.stderr[-2000:])
        result = json.loads((tmp_path / "verify_run" / "result.json").read_text())
        got[data.name] = result["metrics"]
        report = (tmp_path / "verify_run" / "report" / "report.md").read_text()
        assert result["rendered"] and report.startswith("# Detector check on rendered images")
        assert "These are rendered images" in report and "only meaningful for a detector that is good" in report
        shutil.rmtree(tmp_path / "verify_run")
    yolo, coco = got["run"], got["coco.json"]
    assert yolo["images"] == coco["images"] == 3 and yolo["targets"] == coco["targets"] >= 3
    assert yolo["recall"] == pytest.approx(coco["recall"]) and yolo["map50"] == pytest.approx(coco["map50"], abs=0.02)


@pytest.mark.detect
def test_sigterm_ends_the_verify_run_killed(photos, tmp_path, monkeypatch):
    """SIGTERM while scoring: the run ends KILLED, the command exits 143 with one line (a bare traceback before)."""
    from conftest import run_statuses, seed_store, sigterm_here

    from garage_exp.verify import score

    monkeypatch.setattr(score, "score", sigterm_here)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    seed_store([f"tracking.uri={uri}"], tmp_path)
    r = run_verify([f"data={photos / 'coco.json'}", "+label_map.pedestrian=person", f"detector.models=[{YOLO}]"],
                   tmp_path, uri)
    assert r.returncode == 143, r.stderr[-2000:]
    assert r.stderr.strip().splitlines()[-1] == "garage_exp.verify: terminated (SIGTERM)"
    assert run_statuses(uri, "garage_verify") == ["KILLED"]


def test_ap50_is_cocos_and_the_loop_uses_it(tmp_path):
    """results.cocoeval.ap50 (shared by verify and the loop's held-out scoring): 1 when every object is found
    above every false alarm; with a false alarm ranked above the one of two objects found, precision 0.5 up to
    recall 0.5 and nothing past it: 51 of COCO's 101 recall points at 0.5; 0 without detections."""
    from types import SimpleNamespace

    from garage_exp.loop.evaluate import map50
    from garage_exp.results.cocoeval import ap50

    gt = {"images": [{"id": 1, "width": 100, "height": 100}],
          "annotations": [{"id": 1, "image_id": 1, "category_id": 3, "bbox": [10, 10, 20, 20], "area": 400, "iscrowd": 0},
                          {"id": 2, "image_id": 1, "category_id": 3, "bbox": [60, 60, 20, 20], "area": 400, "iscrowd": 0}],
          "categories": [{"id": 3, "name": "car"}]}
    hit = lambda box, score: {"image_id": 1, "category_id": 3, "bbox": box, "score": score}  # noqa: E731
    assert ap50(gt, [hit([10, 10, 20, 20], 0.9), hit([60, 60, 20, 20], 0.8), hit([0, 80, 5, 5], 0.1)]) == \
        pytest.approx(1.0)
    assert ap50(gt, [hit([0, 80, 5, 5], 0.9), hit([10, 10, 20, 20], 0.8)]) == pytest.approx(51 * 0.5 / 101)
    assert ap50(gt, []) == 0.0
    (tmp_path / "coco.json").write_text(json.dumps({**gt, "images": [{**gt["images"][0], "file_name": "a.png"}]}))
    trial = SimpleNamespace(number=0, dataset=tmp_path)
    assert map50([trial], [(0, "a.png", 3, [10, 10, 20, 20], 0.9), (0, "a.png", 3, [60, 60, 20, 20], 0.8)]) == \
        pytest.approx(1.0)


@pytest.mark.detect
def test_verify_a_detector_behind_a_model_server(photos, tmp_path):
    """Any configured detector: yolo11n served over KServe v2 scores as the local yolo11n does on this machine
    (recall 6/7, mAP50 1, and the same false positives: the INT8 kernels of an AVX2 and an AVX-512 machine round
    differently, and an AVX2 machine finds one more false positive on the two photos, so the local run on the same
    machine is the reference, not a number)."""
    from garage_exp.assets.locate import models_dir
    from kserve_server import Server

    def metrics(models: str, folder: Path) -> dict:
        folder.mkdir()
        r = run_verify([f"data={photos / 'data.yaml'}", "+label_map.pedestrian=person", f"detector.models={models}"],
                       folder, f"sqlite:///{folder / 'mlflow.db'}")
        assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:])
        return json.loads((folder / "verify_run" / "result.json").read_text())["metrics"]

    local = metrics(f"[{YOLO}]", tmp_path / "local")
    with Server({"yolo": models_dir() / YOLO}) as server:
        served = metrics(f"[{server.url('yolo')}]", tmp_path / "served")
    assert served["recall"] == pytest.approx(6 / 7) and served["map50/yolo"] == pytest.approx(1.0)
    assert served["fp_per_image/yolo"] in (0.5, 1.0)  # 1 false positive on the two photos (AVX-512), or 2 (AVX2)
    for name in ("recall", "map50", "fp_per_image"):
        assert served[f"{name}/yolo"] == pytest.approx(local[f"{name}/yolo11n_int8"]), name
