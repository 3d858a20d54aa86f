"""Preflight's order (issue 42, item 11): the checks that need no model (config, plan, scene, disk space) come
before the one that loads every detector model, so that a refusal of the first kind costs no model loading;
and the loaders' own lines ("Loading ... for OpenVINO inference", "loaded openvino model ...") go to the log
file, not the terminal."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from conftest import require, run_app
from test_world_faults import one_line_error, shutil_usage


@pytest.fixture
def small_disk(tmp_path, monkeypatch):
    """A folder whose filesystem reports 1 MB free (the probe is patched for it only)."""
    import shutil

    from garage_exp.run import diskspace

    fs = tmp_path / "fs"
    fs.mkdir()
    real_usage = shutil.disk_usage
    monkeypatch.setattr(diskspace.shutil, "disk_usage", lambda path: shutil_usage(free=1 << 20)
                        if Path(path).absolute().is_relative_to(fs) else real_usage(path))
    return fs


@pytest.mark.parametrize("sweep", [True, False], ids=["sweep", "job"])
def test_a_disk_space_refusal_comes_before_any_model_is_loaded(small_disk, monkeypatch, sweep):
    """A real (not dry) run on a disk with 1 MB free, with a detector entry that exists but would fail to load
    (a text file named .onnx): the refusal is the disk's, and no model was loaded. Before, preflight loaded
    every detector first: the load's error came instead (or, with good models, ten lines of loading)."""
    require("assets")
    from garage_exp.run import preflight

    loads = []
    real = preflight.check_loads
    monkeypatch.setattr(preflight, "check_loads", lambda detector, scene: loads.append(detector) or
                        real(detector, scene))
    broken = small_disk.parent / "broken.onnx"
    broken.write_text("not a model\n")
    args = ["plan=tiny", "camera.width=160", "camera.height=120", f"detector.models=[{broken}]",
            f"tracking.uri=sqlite:///{small_disk}/mlflow.db"]
    proc = run_app(["-m", *args, "light=bright,dim"] if sweep else args, small_disk, fresh_store=True)
    line = one_line_error(proc.stderr)
    assert proc.returncode == 2, proc.stderr[-3000:]
    what = "the sweep (2 jobs)" if sweep else "this job"
    assert f"not enough free disk space: {what} will write about" in line, line
    assert loads == [], "a model was loaded before the disk-space check"
    assert [p for p in small_disk.rglob("*") if p.is_file()] == []


def test_the_loaders_lines_go_to_the_log_file_not_the_terminal(tmp_path, capsys):
    """ultralytics prints "Loading ... for OpenVINO inference..." on stdout and the project logged "loaded
    openvino model ... in 1.2 s" on the terminal; both belong in the job's log file."""
    require("models")
    from garage_exp.assets.locate import models_dir
    from garage_exp.perception.detect.ultralytics_entry import load_model

    path = models_dir() / "yolo11n_int8_openvino_model"
    log_file = tmp_path / "app.log"
    handler = logging.FileHandler(log_file)
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        capsys.readouterr()
        load_model(path, imgsz=160)
        out = capsys.readouterr()
    finally:
        root.removeHandler(handler)
        handler.close()
    said = log_file.read_text()
    assert f"Loading {path} for OpenVINO inference" in said and "loaded openvino model yolo11n_int8" in said, said
    assert "Loading" not in out.out + out.err and "loaded openvino" not in out.out + out.err, out
