"""The conftest hook: a skipped render/detect/slow test is an error where the machine has what it needs or
under CI=true, and stays a skip where the machine lacks it. Checked on a scratch test file in a pytest
subprocess that uses this conftest."""

from __future__ import annotations

import shutil
import subprocess

from conftest import PYTHON, ROOT, child_env

SCRATCH = '''
import pytest
from conftest import require

@pytest.mark.detect
def test_marked_skip():
    pytest.skip("pretend the weights are gone")

@pytest.mark.detect
def test_required_models():
    require("models")

def test_unmarked_skip():
    pytest.skip("nothing to do with the product's assets")
'''


def run_scratch(tmp_path, env: dict) -> str:
    tests = tmp_path / "tests"
    tests.mkdir(exist_ok=True)
    shutil.copy(ROOT / "tests" / "conftest.py", tests / "conftest.py")
    shutil.copytree(ROOT / "conf", tmp_path / "conf", dirs_exist_ok=True)  # the default detector's model list
    (tests / "test_scratch.py").write_text(SCRATCH)
    (tmp_path / "pytest.ini").write_text("[pytest]\nmarkers =\n    detect: x\n")
    r = subprocess.run([PYTHON, "-m", "pytest", "-v", "-p", "no:cacheprovider", "tests"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300, env=child_env(env))
    return r.stdout


def outcome(out: str, name: str) -> str:
    """The -v line's verdict: "tests/test_scratch.py::NAME SKIPPED (reason) [ 33%]" -> SKIPPED."""
    line = next(ln for ln in out.splitlines() if f"::{name} " in ln)
    return line.split(f"::{name} ")[1].split()[0]


def test_skips_stay_skips_where_the_weights_are_missing(tmp_path):
    empty = tmp_path / "no_models"
    empty.mkdir()
    out = run_scratch(tmp_path, {"CI": "", "GARAGE_EXP_PROVISIONED": "", "GARAGE_EXP_MODELS": str(empty)})
    assert outcome(out, "test_marked_skip") == "SKIPPED", out
    assert outcome(out, "test_required_models") == "SKIPPED", out
    assert outcome(out, "test_unmarked_skip") == "SKIPPED", out


def test_skips_are_errors_under_ci(tmp_path):
    empty = tmp_path / "no_models"
    empty.mkdir()
    out = run_scratch(tmp_path, {"CI": "true", "GARAGE_EXP_MODELS": str(empty)})
    assert outcome(out, "test_marked_skip") == "FAILED", out
    assert "skip is an error here (CI=true or make test): pretend the weights are gone" in out
    assert outcome(out, "test_required_models") == "FAILED", out
    assert outcome(out, "test_unmarked_skip") == "SKIPPED", out  # only the product's own needs are enforced


def test_a_skip_is_an_error_where_the_machine_has_the_weights(tmp_path):
    models = tmp_path / "models"
    for name in ("yolo11n_int8_openvino_model", "yolov8n_int8_openvino_model", "yolo26n_int8_openvino_model"):
        (models / name).mkdir(parents=True)  # what the product's lookup looks for (no need for real weights)
    out = run_scratch(tmp_path, {"CI": "", "GARAGE_EXP_PROVISIONED": "", "GARAGE_EXP_MODELS": str(models)})
    assert outcome(out, "test_marked_skip") == "FAILED", out
    assert "this machine has the Vulkan device, vehicles and weights it needs" in out
    assert outcome(out, "test_required_models") == "PASSED", out
    assert outcome(out, "test_unmarked_skip") == "SKIPPED", out
