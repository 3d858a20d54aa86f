"""`python -m garage_exp.train` (issue 22): a tiny training through the real command line (4 rendered QVGA frames,
1 epoch, 128 px) that registers a version, whose weights load as a detector and score a job; the split by scenario;
each bad input refused in one line with exit 2 and nothing written or registered (the loop's tests: test_loop.py)."""

import json
import shutil
from pathlib import Path

import pytest
import yaml

from conftest import require, run_app

NAME = "garage-detector"
# Two frames a scenario at QVGA: the training sees 128 px images, so more or larger frames prove nothing more.
FRAMES = ["case.motion.start=12", "case.motion.end=11.5", "palette.target_colours=[black]", "dataset=true",
          "renderer.save_frames=none", "camera.width=320", "camera.height=240"]


def run_train(args: list[str], cwd: Path, uri: str):
    """What `python -m garage_exp.train ARGS` does, in this process (as conftest.run_in_process does for
    `python -m garage_exp`): exit code, stdout and stderr."""
    from garage_exp.train.app import cli

    return run_entry(cli, [*args, f"tracking.uri={uri}", f"hydra.run.dir={cwd}/train_run", "workers=0"], cwd)


def run_entry(cli, argv: list[str], cwd: Path):
    """An entry point run in this process as conftest.run_app runs the main one: Hydra's globals, its job
    logging on the root logger and the process state are reset after it, as at a process's end."""
    from conftest import run_in_process

    return run_in_process(argv, cwd, entry=cli)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """Two rendered scenarios (two seeds of case 1, 2 frames each: 4 images with labels) and a store."""
    require("vulkan", "vehicles", "models")
    tmp = tmp_path_factory.mktemp("train")
    uri = f"sqlite:///{tmp / 'mlflow.db'}"
    r = run_app(["-m", "seed=0,1", *FRAMES, f"tracking.uri={uri}"], tmp)
    assert r.returncode == 0, r.stderr[-2000:]
    jobs = sorted((tmp / "sweep").glob("[0-9]*"))
    assert len(jobs) == 2 and all(len(list((j / "dataset" / "images").glob("*.png"))) == 2 for j in jobs)
    return tmp, uri, jobs


@pytest.fixture(scope="module")
def trained(work):
    tmp, uri, jobs = work
    r = run_train([f"data=[{jobs[0]},{jobs[1]}/dataset/data.yaml]", "epochs=1", "imgsz=128", "batch=4",
                   "study=test_study"], tmp, uri)
    assert r.returncode == 0, (r.stdout[-3000:], r.stderr[-3000:])
    return tmp, uri, jobs, r


def versions(uri: str) -> list:
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=uri)
    return client.search_model_versions(f"name = '{NAME}'")


def runs(uri: str) -> int:
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name("garage_train")
    return 0 if exp is None else len(client.search_runs([exp.experiment_id]))


@pytest.mark.slow
def test_training_is_tracked_and_registered(trained):
    import mlflow

    tmp, uri, jobs, r = trained
    assert f"registered as models:/{NAME}/1" in r.stdout
    (version,) = versions(uri)
    assert version.tags["base"] == "yolov8n.yaml" and version.tags["study"] == "test_study"
    data = json.loads(version.tags["data"])
    assert data["train_frames"] + data["val_frames"] == 4 and data["train_scenarios"] == data["val_scenarios"] == 1
    client = mlflow.MlflowClient(tracking_uri=uri)
    run = client.get_run(version.run_id)
    assert run.info.status == "FINISHED" and run.data.params["epochs"] == "1"
    history = client.get_metric_history(version.run_id, "metrics/mAP50_B")
    assert [m.step for m in history] == [1]  # one value per epoch
    assert client.get_metric_history(version.run_id, "train/box_loss")[0].value > 0
    artifacts = {a.path for a in client.list_artifacts(version.run_id, "weights")} | \
                {a.path for a in client.list_artifacts(version.run_id, "data")}
    assert {"weights/best.pt", "data/manifest.csv"} <= artifacts


@pytest.mark.slow
def test_split_is_by_scenario(trained):
    import pandas as pd

    tmp = trained[0]
    manifest = pd.read_csv(tmp / "train_run" / "data" / "manifest.csv")
    sides = manifest.groupby("scenario").split.nunique()
    assert (sides == 1).all() and set(manifest.split) == {"train", "val"}
    train = (tmp / "train_run" / "data" / "train.txt").read_text().split()
    val = (tmp / "train_run" / "data" / "val.txt").read_text().split()
    assert len(train) == len(val) == 2
    assert {Path(p).parent.parent for p in train}.isdisjoint({Path(p).parent.parent for p in val})


@pytest.mark.slow
def test_registered_weights_load_and_score_a_job(trained):
    from garage_exp.perception.detect import Detector, resolve

    tmp, uri, jobs, _ = trained
    path = Path(resolve(f"models:/{NAME}/1", uri))
    assert path.name == f"{NAME}_v1.pt"
    detector = Detector(models=[path], imgsz=128)
    detector.check()
    assert {"car", "truck", "bus", "person"} <= set(detector.entries[0].classes)
    (tmp / "score").mkdir()
    r = run_app([f"detector.models=[models:/{NAME}/latest]", "detector.imgsz=128", *FRAMES,
                 f"tracking.uri={uri}"], tmp / "score")
    assert r.returncode == 0, r.stderr[-2000:]
    import pandas as pd

    table = pd.read_csv(tmp / "score" / "run" / "frames.csv")
    assert f"conf_{NAME}_v1" in table.columns and len(table) == 2


def write_dataset(root: Path, label: str = "2 0.5 0.5 0.2 0.2\n", names=None) -> Path:
    """A dataset folder as a job writes it (no rendering: the checks refuse it before any image is read)."""
    from PIL import Image

    from garage_exp.results.labels import coco_names

    (root / "images").mkdir(parents=True)
    (root / "labels").mkdir()
    Image.new("RGB", (64, 48)).save(root / "images" / "0000_front.png")
    (root / "labels" / "0000_front.txt").write_text(label)
    (root / "data.yaml").write_text(yaml.safe_dump({"path": str(root), "train": "images", "val": "images",
                                                    "names": names or coco_names()}))
    return root


def bad_inputs(tmp: Path, jobs: list[Path]) -> dict[str, tuple[list[str], list[str]]]:
    """id -> (arguments, what the one line must say)."""
    empty = tmp / "bad" / "empty_suite"
    (empty / "dataset" / "images").mkdir(parents=True)
    (empty / "manifest.csv").write_text("scenario,band\n")
    (empty / "dataset" / "data.yaml").write_text(yaml.safe_dump({"train": ["images"], "names": {0: "person"}}))
    no_dataset = tmp / "bad" / "suite_without_dataset"
    no_dataset.mkdir()
    (no_dataset / "manifest.csv").write_text("scenario,band\n")
    outside = write_dataset(tmp / "bad" / "outside", "2 0.5 0.5 0.2 0.2\n2 0.95 0.5 0.3 0.2\n")
    other_map = write_dataset(tmp / "bad" / "other_map", "0 0.5 0.5 0.2 0.2\n", {0: "forklift"})
    fake = tmp / "bad" / "fake.pt"
    fake.write_bytes(b"not a torch checkpoint" * 10)
    data = f"data=[{jobs[0]},{jobs[1]}]"
    return {
        "missing-suite": ([f"data=[{tmp}/no_such_suite]"], ["data[0]", "no_such_suite", "not found"]),
        "empty-suite": ([f"data=[{empty}]"], ["data[0]", "no images", "empty"]),
        "suite-without-dataset": ([f"data=[{no_dataset}]"], ["suite_without_dataset", "dataset=true"]),
        "label-outside-image": ([data, f"val=[{outside}]"], ["0000_front.txt", "line 2", "outside the image"]),
        "pt-not-a-detector": ([data, f"base={fake}"], ["fake.pt", "not a detector"]),
        "class-map-mismatch": ([data, f"val=[{other_map}]"], ["val[0]", "class map", "forklift"]),
        "registry-name-unknown": ([data, "base=models:/garage-detectr/1"],
                                  ["base", "no registered model 'garage-detectr'", "did you mean 'garage-detector'"]),
        "registry-version-unknown": ([data, f"base=models:/{NAME}/99"], ["base", "has no version 99", "have: 1"]),
        "one-scenario": ([f"data=[{jobs[0]}]"], ["data", "at least 2"]),
        "imgsz-not-stride": ([data, "imgsz=100"], ["imgsz", "multiple of 32"]),
        "unknown-key": ([data, "+epochz=3"], ["epochz"]),
        "bn-calibrate-yaml-base": ([data, "bn_calibrate=8"], ["bn_calibrate", "a model YAML has none trained"]),
    }


BAD = ["missing-suite", "empty-suite", "suite-without-dataset", "label-outside-image", "pt-not-a-detector",
       "class-map-mismatch", "registry-name-unknown", "registry-version-unknown", "one-scenario",
       "imgsz-not-stride", "unknown-key", "bn-calibrate-yaml-base"]


@pytest.fixture(scope="module")
def bad(trained):
    tmp, uri, jobs, _ = trained
    return bad_inputs(tmp, jobs)


@pytest.mark.slow
@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_one_line_and_registers_nothing(trained, bad, case, tmp_path):
    _, uri, _, _ = trained
    args, expect = bad[case]
    before = (len(versions(uri)), runs(uri))
    r = run_train(args, tmp_path, uri)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr[-2000:]
    for text in expect:
        assert text in lines[0], (text, lines[0])
    assert (len(versions(uri)), runs(uri)) == before
    assert not (tmp_path / "train_run").exists()


@pytest.mark.slow
def test_a_job_refuses_a_version_the_registry_lacks(trained):
    tmp, uri, _, _ = trained
    (tmp / "refused").mkdir()
    r = run_app([f"detector.models=[models:/{NAME}/7]", f"tracking.uri={uri}"], tmp / "refused")
    assert r.returncode == 2
    assert "detector.models" in r.stderr and "has no version 7 (have: 1)" in r.stderr


def test_split_never_puts_a_scenario_on_both_sides(tmp_path):
    """Six scenarios of three frames: every seed holds whole scenarios out, and the replay never draws from them."""
    from omegaconf import OmegaConf

    from garage_exp.train.data import plan_data

    sets = []
    for k in range(6):
        root = write_dataset(tmp_path / f"scenario{k}")
        for j in (1, 2):
            shutil.copy(root / "images" / "0000_front.png", root / "images" / f"000{j}_front.png")
            shutil.copy(root / "labels" / "0000_front.txt", root / "labels" / f"000{j}_front.txt")
        sets.append(str(root))
    for seed in range(5):
        cfg = OmegaConf.create({"data": sets, "val": [], "val_fraction": 0.3, "replay": sets, "replay_fraction": 0.5,
                                "seed": seed})
        plan = plan_data(cfg)
        val = set(plan.scenarios("val"))
        assert len(val) == 2 and len(plan.scenarios("train")) == 4
        assert val.isdisjoint(plan.scenarios("train")) and val.isdisjoint(plan.scenarios("replay"))
        assert len(plan.train) == 12 and len(plan.replay) == 6 and len(plan.val) == 6


@pytest.mark.slow
def test_an_onnx_export_of_the_trained_model_detects_as_its_pt(trained, tmp_path):
    """The trained project model exported by ultralytics to ONNX gives the same detections as its .pt: on the
    rendered frames it was trained on, every candidate detection before non-maximum suppression (all 84 x N
    outputs: box centre and size in pixels, 80 class scores) agrees within 0.01 px and 1e-4 (docs/perception.md
    states this tolerance), and the ONNX file runs as a detector entry. After one epoch every candidate scores
    near its prior (~1e-4), so which of the tied boxes NMS keeps is arbitrary: the candidates are compared, not
    the kept boxes."""
    import numpy as np
    import onnxruntime
    import torch
    from PIL import Image
    from ultralytics import YOLO
    from ultralytics.data.augment import LetterBox

    from garage_exp.perception.detect import Detector, resolve

    tmp, uri, jobs, _ = trained
    pt = tmp_path / "trained.pt"
    shutil.copyfile(resolve(f"models:/{NAME}/1", uri), pt)
    # dynamic: the graph takes the .pt's rectangular (letterboxed to a multiple of 32) input, not a fixed square
    onnx = YOLO(str(pt)).export(format="onnx", imgsz=128, dynamic=True, simplify=False)
    images = sorted(p for job in jobs for p in (job / "dataset" / "images").glob("*.png"))
    frames = [np.asarray(Image.open(p).convert("RGB")) for p in images]
    network = YOLO(str(pt)).model.float().eval()
    session = onnxruntime.InferenceSession(onnx, providers=["CPUExecutionProvider"])
    for rgb in frames:
        image = LetterBox((128, 128), auto=True, stride=32)(image=rgb[..., ::-1])  # as ultralytics' predictor
        tensor = torch.from_numpy(np.ascontiguousarray(image[..., ::-1].transpose(2, 0, 1))).float()[None] / 255.0
        with torch.no_grad():
            ours = network(tensor)[0].numpy()
        theirs = session.run(None, {session.get_inputs()[0].name: tensor.numpy()})[0]
        assert ours.shape == theirs.shape and ours.shape[1] == 84 and ours.shape[2] > 100
        assert np.abs(ours[:, :4] - theirs[:, :4]).max() <= 0.01  # boxes, pixels
        assert np.abs(ours[:, 4:] - theirs[:, 4:]).max() <= 1e-4  # class scores
    found = Detector([onnx], conf=0.0, imgsz=128, device="cpu").detect(frames[:2])
    assert [d.model for (d,) in found] == ["trained", "trained"] and all(len(d) for (d,) in found)



def test_training_data_leaves_the_inputs_untouched(tmp_path):
    """ultralytics writes labels.cache beside the labels it reads: the lists name links under the run's data/
    folder, so the cache lands there and the input suites stay as they were (issue 31, item 12)."""
    from omegaconf import OmegaConf
    from ultralytics.data.dataset import YOLODataset

    from garage_exp.core.offline import prepare_offline
    from garage_exp.train.data import plan_data, write_data

    prepare_offline()
    sets = [str(write_dataset(tmp_path / "inputs" / f"scenario{k}")) for k in range(2)]
    before = sorted(p for p in (tmp_path / "inputs").rglob("*"))
    cfg = OmegaConf.create({"data": sets, "val": [], "val_fraction": 0.5, "replay": [], "replay_fraction": 0.0,
                            "seed": 0})
    data_yaml = write_data(plan_data(cfg), tmp_path / "out")
    spec = yaml.safe_load(data_yaml.read_text())
    for split in ("train", "val"):
        dataset = YOLODataset(img_path=str(tmp_path / "out" / spec[split]), imgsz=64, augment=False,
                              data={"names": spec["names"], "channels": 3})
        assert len(dataset.labels) == 1 and dataset.labels[0]["cls"].tolist() == [[2.0]]
    assert sorted(p for p in (tmp_path / "inputs").rglob("*")) == before
    assert len(list((tmp_path / "out").rglob("labels.cache"))) == 2


def test_an_unknown_base_is_named_once(tmp_path):
    from garage_exp.core.errors import GarageError
    from garage_exp.train.base import load_base

    with pytest.raises(GarageError) as caught:
        load_base(str(tmp_path / "weights.txt"), None)
    assert str(caught.value).startswith("base: ") and "base: base:" not in str(caught.value)


def test_sigterm_ends_the_training_run_killed(tmp_path, monkeypatch, mlflow_uri):
    """SIGTERM (a scheduler's limit, the loop stopped) during the training: its MLflow run ends KILLED, not RUNNING,
    and the command exits 143 with one line, as `python -m garage_exp` does (it raised a bare traceback before)."""
    from conftest import run_statuses, seed_store, sigterm_here

    from garage_exp.train import fit

    monkeypatch.setattr(fit, "fit", sigterm_here)
    sets = [str(write_dataset(tmp_path / f"scenario{k}")) for k in range(2)]
    seed_store([f"tracking.uri={mlflow_uri}"], tmp_path)
    r = run_train([f"data=[{','.join(sets)}]", "val_fraction=0.5", "epochs=1", "imgsz=64"], tmp_path, mlflow_uri)
    assert r.returncode == 143, r.stderr[-2000:]
    assert r.stderr.strip().splitlines()[-1] == "garage_exp.train: terminated (SIGTERM)"
    assert run_statuses(mlflow_uri, "garage_train") == ["KILLED"]

