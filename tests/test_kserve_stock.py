"""A stock KServe server (issue 42, item 1): not the test server this project wrote (tests/kserve_server.py) but
kserve 0.21 itself, a plain `kserve.Model` serving yolo11n (the float yolo11n of ../shared/models, exported to ONNX
here) behind kserve's own REST server, as docs/perception.md shows it. Its metadata has no `parameters` and it has
no config route, so it cannot say its class names: the config gives them (`detector.class_names.NAME`).

kserve pins a protobuf, pandas and psutil older than the project's, so the server runs from its own environment,
.venv-kserve (`make python` makes it; $GARAGE_EXP_KSERVE_PYTHON names another interpreter). The server binds
127.0.0.1 on a free port, in its own session, and is killed by its pid on every path."""

from __future__ import annotations

import json
import os
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, STRICT_CI, require, run_app
from kserve_server import Server

from garage_exp.core.errors import GarageError

FRAMES = ["case=1", "case.motion.start=12", "case.motion.end=11", "palette.target_colours=[black]",
          "renderer.save_frames=none", "camera.width=320", "camera.height=240"]


def kserve_python() -> str:
    python = os.environ.get("GARAGE_EXP_KSERVE_PYTHON") or str(ROOT / ".venv-kserve" / "bin" / "python")
    if not Path(python).is_file():
        problem = f"no kserve environment at {python} (`make python` makes .venv-kserve)"
        if STRICT_CI:
            pytest.fail(problem)
        pytest.skip(problem)
    return python


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """yolo11n (float, from ../shared/models) exported to ONNX with the export the docs show (640 x 640, simplified
    with onnxslim, which the set-up ships), served by kserve: (the server, the ONNX file, a names file)."""
    from garage_exp.assets.locate import models_dir

    python = kserve_python()
    require("models")
    pt = models_dir() / "yolo11n_fp32_from_int8.pt"
    if not pt.is_file():
        (pytest.fail if STRICT_CI else pytest.skip)(f"{pt} is missing")
    from ultralytics import YOLO

    tmp = tmp_path_factory.mktemp("kserve")
    (tmp / "yolo11n.pt").symlink_to(pt)
    model = YOLO(str(tmp / "yolo11n.pt"))
    onnx = Path(model.export(format="onnx"))
    names = tmp / "names.yaml"  # the names as the docs write them: from the .pt, index -> name
    names.write_text(json.dumps({"names": model.names}))
    server = Server({"yolo": onnx}, log=tmp / "server.log")
    server.command = [python, str(ROOT / "tests" / "kserve_stock.py")]
    try:
        yield server.start(timeout=120), onnx, names
    finally:
        server.stop()


def photo(name: str) -> np.ndarray:
    import ultralytics
    from PIL import Image

    with Image.open(Path(ultralytics.__file__).parent / "assets" / name) as im:
        return np.asarray(im.convert("RGB"))


def test_a_stock_kserve_server_gives_no_names_and_the_refusal_says_how_to_give_them(served):
    from garage_exp.perception.detect import make_detector

    server, _, _ = served
    with urllib.request.urlopen(server.url("yolo"), timeout=10) as r:
        meta = json.load(r)
    assert "parameters" not in meta and meta["inputs"][0]["shape"] == [1, 3, 640, 640]
    with pytest.raises(urllib.error.HTTPError) as no_config:
        urllib.request.urlopen(server.url("yolo") + "/config", timeout=10)
    assert no_config.value.code == 404
    with pytest.raises(GarageError, match=r"gives no class names .*\+detector.class_names.yolo=") as err:
        make_detector(models=[server.url("yolo")]).check()
    assert err.value.where == f"detector.models {server.url('yolo')}"


def test_names_from_the_config_give_the_local_models_detections(served):
    """The served yolo11n, its names from a file, against the same graph run here by ultralytics: every detection
    scored 0.25 or more matches, box within 1 px, score within 0.01; bus.jpg's bus is found at 0.94."""
    from garage_exp.perception.detect import make_detector

    server, onnx, names = served
    detector = make_detector(models=[server.url("yolo"), str(onnx)], class_names={"yolo": str(names)})
    assert detector.names == ["yolo", "yolo11n"]
    for image in ("bus.jpg", "zidane.jpg"):
        remote, local = detector.detect([photo(image)])[0]
        keep_r, keep_l = remote.scores >= 0.25, local.scores >= 0.25
        assert keep_r.sum() == keep_l.sum() >= 2, image
        order_r, order_l = np.argsort(-remote.scores[keep_r]), np.argsort(-local.scores[keep_l])
        assert [np.array(remote.classes)[keep_r][k] for k in order_r] == \
            [np.array(local.classes)[keep_l][k] for k in order_l]
        np.testing.assert_allclose(remote.scores[keep_r][order_r], local.scores[keep_l][order_l], atol=0.01)
        np.testing.assert_allclose(remote.boxes[keep_r][order_r], local.boxes[keep_l][order_l], atol=1.0)
        if image == "bus.jpg":
            assert "bus" in remote.classes and remote.scores[remote.classes.index("bus")] > 0.9


@pytest.mark.render
@pytest.mark.slow
def test_a_job_scores_with_the_stock_server(served, tmp_path, mlflow_uri):
    """The docs' command line: a 3-frame job with the served model, its names given on the command line; the
    black car ahead is found (the frame table's column for the served model holds its confidences)."""
    require("vulkan", "vehicles", "models")
    server, _, names = served
    r = run_app([*FRAMES, f"detector.models=[{server.url('yolo')}]", f"+detector.class_names.yolo={names}",
                 f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    import csv

    with open(tmp_path / "run" / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 and any(float(row["conf_yolo"]) > 0.3 for row in rows), rows
