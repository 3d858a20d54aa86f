"""The maintenance commands the README lists: `make map`, `make clean`, `python -m garage_exp.assets convert`.
Make targets are read with `make -n` (nothing runs, no venv is built) or run in a scratch copy; the commands
they stand for run for real on scratch outputs."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import PYTHON, ROOT, child_env, require, run_module


def make_n(target: str) -> str:
    r = subprocess.run(["make", "-n", target], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_make_map_draws_every_shipped_plan(tmp_path):
    line = next(ln for ln in make_n("map").splitlines() if "garage_exp.plan map" in ln)
    assert "plans/*.yaml plans/*.csv" in line and "-o outputs/maps/" in line
    plans = sorted([*ROOT.glob("plans/*.yaml"), *ROOT.glob("plans/*.csv")])
    assert len(plans) >= 5
    for plan in plans:  # what the loop runs, writing into tmp_path instead of outputs/maps/ (in this process)
        out = tmp_path / f"{plan.stem}.png"
        r = run_module("garage_exp.plan", ["map", str(plan), "-o", str(out)], ROOT)
        assert r.returncode == 0, (plan.name, r.stderr[-2000:])
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 5000, plan.name


def test_make_clean_removes_outputs_and_nothing_else(tmp_path):
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    (tmp_path / "outputs" / "runs").mkdir(parents=True)
    (tmp_path / "outputs" / "mlflow.db").write_text("x")
    (tmp_path / "plans").mkdir()
    (tmp_path / "plans" / "mine.yaml").write_text("S: [[1]]\n")
    r = subprocess.run(["make", "clean"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert not (tmp_path / "outputs").exists()
    assert (tmp_path / "plans" / "mine.yaml").read_text() == "S: [[1]]\n" and (tmp_path / "Makefile").exists()


@pytest.mark.slow
def test_assets_convert_converts_and_lists_the_vehicles(tmp_path):
    """`python -m garage_exp.assets convert` on a folder of two FlightGear cars (found through the product's
    lookup), with an empty cache: both converted to GLB and listed with their size class."""
    require("vehicles")
    from garage_exp.assets.locate import vehicles_dir

    source = tmp_path / "ac"
    source.mkdir()
    for name in ("tcamryblack", "camarowhite"):
        for path in vehicles_dir().glob(f"{name}*"):
            shutil.copy(path, source / path.name)
    env = child_env({"GARAGE_EXP_ASSETS": str(source), "GARAGE_EXP_CACHE": str(tmp_path / "cache")})
    r = subprocess.run([PYTHON, "-m", "garage_exp.assets", "convert"], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    rows = [ln.split() for ln in r.stdout.splitlines() if ln.strip()]
    assert sorted(row[0] for row in rows) == ["camarowhite", "tcamryblack"]
    for row in rows:
        assert row[7] == "medium" and row[-1].endswith(".glb")  # name L x W x H m class kind colour glb
        assert (tmp_path / "cache") in Path(row[-1]).parents and Path(row[-1]).stat().st_size > 10_000
