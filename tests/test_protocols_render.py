"""The protocol scenarios end to end (docs/protocols.md): one tiny job each (320x240, three frames), rendered,
detected and judged late, as `python -m garage_exp case=...` runs them."""

from __future__ import annotations

import pandas as pd
import pytest
from conftest import run_app

pytestmark = [pytest.mark.render, pytest.mark.detect, pytest.mark.slow]

TINY = ["camera.width=320", "camera.height=240", "renderer.save_frames=none"]


def job(tmp_path, mlflow_uri, *args):
    r = run_app([*args, *TINY, f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "late: " in r.stdout  # the ego drives: the job judges whether it saw the target in time
    out = tmp_path / "run"
    assert (out / "late.csv").is_file()
    return pd.read_csv(out / "frames.csv")


def test_cpnco_child_is_hidden_beyond_the_parked_cars_then_seen_stepping_out(tmp_path, mlflow_uri):
    table = job(tmp_path, mlflow_uri, "case=cpnco", "case.motion.start=9.0", "case.motion.end=5.0",
                "case.motion.step=2.0")
    assert table.position.tolist() == [9.0, 7.0, 5.0] and set(table.target) == {"child"}
    assert table.visible_fraction.iloc[0] < 0.6  # still behind the smaller car
    assert table.visible_fraction.iloc[-1] == 1.0  # in the lane


def test_cpra_reversing_ego_is_scored_by_its_rear_camera(tmp_path, mlflow_uri):
    table = job(tmp_path, mlflow_uri, "case=cpra", "camera=rear", "ego.speed=8",
                "case.variants=[{label: adult 50 %, show: [adult], target: adult}]",
                "case.motion.start=6.5", "case.motion.end=3.5", "case.motion.step=1.5")
    assert set(table.camera) == {"rear"} and len(table) == 3
    assert (table.visible_fraction == 1.0).all()  # the adult stands in the lane behind the ego
    assert table.distance.is_monotonic_decreasing  # rear first, toward it


@pytest.mark.parametrize("case, target, start", [("crossing", "walker", 15.0), ("crouch", "person", 9.0)])
def test_avp_situations_run(tmp_path, mlflow_uri, case, target, start):
    """(The crossing's walker sets off when the ego is 15 m away: its first frame.)"""
    step = (start - 5.0) / 2
    table = job(tmp_path, mlflow_uri, f"case={case}", f"case.motion.start={start}", "case.motion.end=5.0",
                f"case.motion.step={step}")
    assert len(table) == 3 and set(table.target) == {target}
