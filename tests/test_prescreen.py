"""The search's pre-screen (garage_exp/search/prescreen.py): on a small fixed set of trials, it never screens out
as easy a trial that the full render (three detectors, full resolution) finds hard; and a search with it prunes
without rendering in full."""

from __future__ import annotations

from pathlib import Path

import optuna
import pytest
from conftest import compose_cfg, run_app

from garage_exp.results.table import fair_summary

pytestmark = [pytest.mark.render, pytest.mark.detect, pytest.mark.slow]

# The lighting case at QVGA (flat look: no auto-exposure to rescue the dark), a black car 6 and 9 m ahead of a
# standing ego: almost no light, a little, and bright light side-on.
BASE = ["case=light", "look=flat", "palette.target_colours=[black]", "camera.width=320", "camera.height=240",
        "detector.imgsz=320", "case.motion.values=[6.0,9.0]", "renderer.save_frames=none",
        "search.prescreen.level=detector"]
SET = [["light.intensity=0.01", "light.ambient=0.0"], ["light.intensity=0.03", "light.ambient=0.01"],
       ["light.intensity=2.0", "case.actors.target.yaw=90.0"]]
HARD = 0.6


def test_the_prescreen_never_screens_out_a_trial_that_the_full_render_finds_hard():
    from garage_exp.perception.detect import build_detector
    from garage_exp.search import prescreen

    verdicts, full_detector = [], None
    for point in SET:
        cfg = compose_cfg(*BASE, *point)
        full_detector = full_detector or build_detector(cfg.detector)
        table, _ = prescreen.frames_table(cfg, full_detector, 1.0)  # the job's frames: full size, three models
        full = fair_summary(table, "front", cfg.search, cfg.detector.threshold)["fair_difficulty"]
        seen = prescreen.look(cfg)
        verdicts.append((point, full, seen.why, seen.attrs.get("prescreen_difficulty")))
    for point, full, why, cheap in verdicts:
        assert not (why == "easy" and full >= HARD), f"{point}: screened as easy ({cheap}), full difficulty {full}"
    # the set is not trivial: it holds a hard trial and one the pre-screen spares its full render
    assert any(full >= HARD for _, full, _, _ in verdicts), verdicts
    assert any(why == "easy" for _, _, why, _ in verdicts), verdicts


# Case 1, the ego 10 to 6 m before the corner: the car beyond it is hidden by the pillar from some distances
# on (then the truth-level pre-screen prunes the trial as infeasible).
CORNER = ["case=1", "palette.target_colours=[black]", "camera.width=320", "camera.height=240",
          "detector.imgsz=320", "case.motion.start=10", "case.motion.end=6", "case.motion.step=1.0",
          "case.actors.target.clip=true", "renderer.save_frames=none"]


def test_a_late_search_with_the_prescreen_prunes_without_the_full_render(tmp_path, mlflow_uri):
    store = tmp_path / "optuna.db"
    proc = run_app(["-m", "hydra/sweeper=search", *CORNER, "search.objective=late", "search.sampler=random",
                    "search.trials=3", "search.prescreen.level=truth", f"search.storage=sqlite:///{store}",
                    "search.study=late", "ego.speed=interval(5.0,20.0)",
                    "case.actors.target.distance=interval(2.0,10.0)", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    study = optuna.load_study(study_name="late", storage=f"sqlite:///{store}")
    trials = study.get_trials()
    assert len(trials) == 3 and all(t.user_attrs.get("prescreen_frames") == 5 for t in trials)
    for t in trials:
        if t.user_attrs.get("screened"):  # never rendered in full: no run, no full frames
            assert t.state == optuna.trial.TrialState.PRUNED and "run_id" not in t.user_attrs
        elif t.state == optuna.trial.TrialState.COMPLETE:
            assert 0.0 <= t.values[0] <= 1.0 and "late" in t.user_attrs and "detection_distance" in t.user_attrs
    report = (Path(tmp_path) / "sweep" / "search" / "search_report.md").read_text()
    assert "lateness" in report
