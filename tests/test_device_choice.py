"""`renderer.device` and `detector.device` (auto | cpu | cuda, issue 24 part 4): which Vulkan ICD and which torch
device each picks, with the machine's GPU, ICD files and CUDA faked (no Vulkan, no torch, no GPU needed). The
command line's side of a bad value (one line, exit 2) is in the bad-input corpus (tests/bad_inputs/cases.yaml)."""

from __future__ import annotations

import fnmatch
import logging

import pytest
from conftest import compose_cfg

from garage_exp.core.errors import GarageError
from garage_exp.perception.detect import detector, devices, ultralytics_entry
from garage_exp.render.open import check_renderer
from garage_exp.render import device, icd

LAVAPIPE = "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json"
NVIDIA = "/usr/share/vulkan/icd.d/nvidia_icd.json"
MOUNTED_NVIDIA = "/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json"


@pytest.fixture
def machine(monkeypatch):
    """A fake machine: `machine(*files)` makes exactly these paths exist for icd.py's globs; no ICD variable
    set; the process has not picked a device yet."""
    for var in icd.ICD_VARS:
        # set, then deleted: monkeypatch records the variable's real state, so what choose_icd writes is undone
        # (a fake ICD left in os.environ would blind every later render in this xdist worker)
        monkeypatch.setenv(var, "unset-by-test")
        monkeypatch.delenv(var)
    monkeypatch.setattr(device, "_DEVICE", {})

    def make(*files: str):
        monkeypatch.setattr(icd.glob, "glob", lambda pattern: sorted(f for f in files
                                                                     if fnmatch.fnmatch(f, pattern)))
    return make


def test_auto_on_a_cpu_machine_points_at_lavapipe(machine, monkeypatch):
    machine(LAVAPIPE)
    assert device.choose_icd("auto") == LAVAPIPE
    assert device.os.environ["VK_ICD_FILENAMES"] == LAVAPIPE


def test_auto_with_an_nvidia_gpu_leaves_the_loader_alone(machine):
    machine("/dev/nvidia0", NVIDIA, LAVAPIPE)
    assert device.choose_icd("auto") is None
    assert "VK_ICD_FILENAMES" not in device.os.environ


def test_auto_finds_an_icd_mounted_where_the_loader_does_not_look(machine):
    machine("/dev/nvidia0", MOUNTED_NVIDIA)
    assert device.choose_icd("auto") == MOUNTED_NVIDIA
    assert device.os.environ["VK_ICD_FILENAMES"] == MOUNTED_NVIDIA


def test_auto_keeps_an_icd_the_user_set(machine, monkeypatch):
    machine(LAVAPIPE)
    monkeypatch.setenv("VK_DRIVER_FILES", "/mine.json")
    assert device.choose_icd("auto") is None
    assert device.os.environ["VK_DRIVER_FILES"] == "/mine.json"


def test_cpu_forces_lavapipe_on_a_gpu_machine(machine, monkeypatch):
    machine("/dev/nvidia0", NVIDIA, LAVAPIPE)
    monkeypatch.setenv("VK_DRIVER_FILES", NVIDIA)
    assert device.choose_icd("cpu") == LAVAPIPE
    assert device.os.environ["VK_ICD_FILENAMES"] == LAVAPIPE
    assert "VK_DRIVER_FILES" not in device.os.environ  # it would win over VK_ICD_FILENAMES


def test_cpu_without_lavapipe_is_refused(machine):
    machine("/dev/nvidia0", NVIDIA)
    with pytest.raises(GarageError, match="renderer.device: cpu needs Mesa's lavapipe"):
        device.choose_icd("cpu")


def test_cuda_picks_the_nvidia_icd(machine):
    machine("/dev/nvidia0", NVIDIA, LAVAPIPE)
    assert device.choose_icd("cuda") == NVIDIA


@pytest.mark.parametrize("files, why", [((LAVAPIPE,), r"no NVIDIA device \(/dev/nvidia0\)"),
                                        (("/dev/nvidia0", LAVAPIPE), r"no NVIDIA Vulkan ICD")])
def test_cuda_without_nvidia_is_refused_saying_what_is_missing(machine, files, why):
    machine(*files)
    with pytest.raises(GarageError, match=f"renderer.device: cuda needs an NVIDIA GPU.*{why}"):
        device.choose_icd("cuda")


def test_an_unknown_device_is_refused(machine):
    machine(LAVAPIPE)
    with pytest.raises(GarageError, match=r"renderer.device: unknown device 'gpu' \(auto \| cpu \| cuda\)"):
        device.choose_icd("gpu")


def test_a_process_keeps_its_first_device(machine, monkeypatch):
    machine("/dev/nvidia0", NVIDIA, LAVAPIPE)
    monkeypatch.setattr(device, "_DEVICE", {"checked": "GPU: llvmpipe (LLVM 15.0.6, 256 bits)", "kind": "cpu"})
    assert device.ensure_device("auto") == device._DEVICE["checked"]
    assert device.ensure_device("cpu") == device._DEVICE["checked"]
    with pytest.raises(GarageError, match="cuda asked, but this process already renders on GPU: llvmpipe"):
        device.ensure_device("cuda")


@pytest.mark.parametrize("name, kind", [("GPU: llvmpipe (LLVM 15.0.6, 256 bits)", "cpu"),
                                        ("GPU: NVIDIA H100 80GB HBM3", "cuda"),
                                        ("GPU: AMD Radeon 780M (RADV PHOENIX)", "gpu")])
def test_device_kind(name, kind):
    assert device.device_kind(name) == kind


@pytest.fixture
def cuda(monkeypatch):
    """cuda(True/False): whether torch 'sees' a CUDA GPU."""
    def make(present: bool):
        monkeypatch.setattr(devices, "cuda_available", lambda: present)
    return make


@pytest.mark.parametrize("asked, kind, present, picked", [
    ("auto", "pt", True, "cuda:0"), ("auto", "pt", False, "cpu"),
    ("auto", "openvino", True, "cpu"),  # INT8 exports stay on OpenVINO's CPU plugin
    ("cpu", "pt", True, "cpu"), ("cuda", "pt", True, "cuda:0"), ("cuda", "openvino", True, "cpu")])
def test_detector_pick(cuda, asked, kind, present, picked):
    cuda(present)
    assert devices.pick_device(asked, cpu_only=kind == "openvino") == picked


@pytest.mark.parametrize("asked, message", [("cuda", "cuda asked, but torch sees no CUDA GPU"),
                                            ("gpu", r"unknown device 'gpu' \(auto \| cpu \| cuda\)")])
def test_detector_refusals(cuda, asked, message):
    cuda(False)
    with pytest.raises(GarageError, match=f"detector.device: {message}"):
        devices.pick_device(asked)


def _entries(tmp_path, asked: str, *names: str) -> list:
    """Ultralytics entries (not loaded) for files or OpenVINO folders of these names."""
    out = []
    for name in names:
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.mkdir() if name.endswith("_openvino_model") else path.write_bytes(b"")
        out.append(ultralytics_entry.UltralyticsEntry(str(path), detector.EntrySettings(device=asked)))
    return out


def test_detector_line_says_where_each_model_runs_and_why(cuda, tmp_path):
    cuda(True)
    entries = _entries(tmp_path, "auto", "yolo11n_int8_openvino_model", "yolov8n_int8_openvino_model", "mine.pt")
    line = devices.device_line("auto", ["yolo11n_int8", "yolov8n_int8", "mine"], entries)
    assert line == "detector device auto -> cpu for yolo11n_int8, yolov8n_int8 (OpenVINO export: CPU only); " \
                   "cuda:0 for mine"
    cuda(False)
    assert devices.device_line("auto", ["mine"], _entries(tmp_path / "x", "auto", "mine.pt")) == \
        "detector device auto -> cpu for mine (torch sees no CUDA GPU)"
    assert devices.device_line("cpu", ["a"], _entries(tmp_path / "y", "cpu", "a_openvino_model")) == \
        "detector device cpu -> cpu for a"


def test_the_detector_logs_its_pick_once_per_process(cuda, monkeypatch, caplog, tmp_path):
    cuda(True)
    weights = tmp_path / "mine.pt"
    weights.write_bytes(b"")
    monkeypatch.setattr(detector, "_SAID", {})
    loaded = []
    monkeypatch.setattr(ultralytics_entry, "load_model",
                        lambda path, imgsz, dev, threads, where: loaded.append(dev) or _Model())
    with caplog.at_level(logging.INFO, logger="garage_exp"):
        first = detector.Detector(models=[weights])
        first.check()
        detector.Detector(models=[weights]).check()
    assert first.devices == ["cuda:0"] and loaded == ["cuda:0"]  # loaded once per process
    said = [r.getMessage() for r in caplog.records if "detector device" in r.getMessage()]
    assert said == ["detector device auto -> cuda:0 for mine"]


class _Model:
    names = {0: "person", 1: "car", 2: "truck", 3: "bus"}


def test_config_defaults_and_checks(cuda):
    cfg = compose_cfg()
    assert cfg.renderer.device == "auto" and cfg.detector.device == "auto"
    check_renderer(cfg.renderer)
    detector.check_detector(cfg.detector)
    cuda(False)
    with pytest.raises(GarageError, match="detector.device: cuda asked"):
        detector.check_detector(compose_cfg("detector.device=cuda").detector)
    with pytest.raises(GarageError, match="renderer.device: unknown device 'vulkan'"):
        check_renderer(compose_cfg("renderer.device=vulkan").renderer)
