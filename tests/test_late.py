"""Seen in time to stop (garage_exp/results/late.py): the arithmetic on hand-made frame tables, the frames' times
and the along-moving child of case=stepout, and the late objective's outcome in the search."""

from __future__ import annotations

import math

import pandas as pd
import pytest
from conftest import compose_cfg
from omegaconf import OmegaConf
from optuna.trial import TrialState

from garage_exp.results import late
from garage_exp.search.loop import line, outcome

# 10 km/h, 0.5 s, 3.4 m/s^2, 2.5 m: stopping 2.778 x 0.5 + 2.778^2 / 6.8 = 2.524 m, critical 5.024 m
EGO = OmegaConf.create({"speed": 10.0, "reaction": 0.5, "deceleration": 3.4, "margin": 2.5, "k": 2, "n": 3})
V = 10 / 3.6


def approach(hits: list[bool], fair: list[bool] | None = None, start: float = 12.0, step: float = 1.0):
    """A target dead ahead, the ego closing at V: distances start, start - step, ...; times from them."""
    d = [start - step * k for k in range(len(hits))]
    t = [step * k / V for k in range(len(hits))]
    return d, t, hits, fair if fair is not None else [True] * len(hits)


def test_stopping_and_critical_distance_follow_the_defaults():
    assert late.stopping_distance(EGO) == pytest.approx(V * 0.5 + V * V / 6.8)
    assert late.stopping_distance(EGO) == pytest.approx(2.524, abs=1e-3)
    assert late.critical_distance(EGO) == pytest.approx(5.024, abs=1e-3)
    fast = OmegaConf.merge(EGO, {"speed": 20.0})
    assert late.stopping_distance(fast) == pytest.approx(2 * V * 0.5 + 4 * V * V / 6.8)


@pytest.mark.parametrize("hits, k, n, expected", [
    ([True, False, True], 2, 3, 2),
    ([True, False, False, True], 2, 3, None),  # two hits, but never two within three frames
    ([False, True, True], 2, 2, 2),
    ([True], 1, 1, 0),
    ([False, False], 1, 3, None),
    ([True, True, False, True, True, True], 3, 3, 5),
])
def test_confirmation_is_k_hits_within_the_last_n_frames(hits, k, n, expected):
    assert late.confirmed_at(hits, k, n) == expected


def test_a_target_confirmed_early_is_in_time():
    v = late.judge(*approach([False, True, True, True, True, True, True, True, True]), EGO)
    assert v.testable and not v.late
    assert v.confirmed_frame == 2 and v.detection_distance == 10.0
    assert v.ttc == pytest.approx(10.0 / V)  # range over closing speed
    assert v.first_fair_distance == 12.0
    assert v.lateness == pytest.approx((12.0 - 10.0) / (12.0 - late.critical_distance(EGO)))


def test_a_target_confirmed_only_inside_the_critical_distance_is_late():
    hits = [False] * 8 + [True, True, True]  # confirmed at frame 9: 3 m, inside 5.02 m
    v = late.judge(*approach(hits), EGO)
    assert v.testable and v.late and v.lateness == 1.0
    assert v.detection_distance == 3.0


def test_a_target_never_confirmed_while_fairly_visible_before_it_is_late():
    v = late.judge(*approach([False] * 10), EGO)
    assert v.testable and v.late and v.lateness == 1.0
    assert math.isnan(v.detection_distance) and math.isnan(v.ttc)


def test_a_target_never_fairly_visible_before_the_critical_distance_is_untestable_not_late():
    hits = [False] * 8 + [True, True, True]
    fair = [False] * 8 + [True, True, True]  # hidden until 4 m: nobody could have seen it in time
    v = late.judge(*approach(hits, fair), EGO)
    assert not v.testable and not v.late and math.isnan(v.lateness)
    assert v.detection_distance == 3.0


def test_a_target_that_peeks_out_for_one_frame_is_untestable():
    """k=2 of n=3: one fair frame before the critical distance is no chance to confirm it in time."""
    fair = [False, False, True, False, False, False, False, False, True, True, True]
    v = late.judge(*approach([False] * 11, fair), EGO)
    assert not v.testable and not v.late
    fair[3] = True  # two fair frames in a row: a perfect detector would have confirmed it at 9 m
    v = late.judge(*approach([False] * 11, fair), EGO)
    assert v.testable and v.late
    # confirmed in time while fairly visible in one frame only (the hits came while it was partly hidden): a
    # test the detectors passed
    hits = [False, True, True] + [False] * 8
    v = late.judge(*approach(hits, [False, False, True] + [False] * 8), EGO)
    assert v.testable and not v.late and v.detection_distance == 10.0 and v.lateness == 0.0
    # confirmed in time and never fairly visible before the critical distance: in time, lateness 0 (not NaN)
    v = late.judge(*approach(hits, [False] * 11), EGO)
    assert v.testable and not v.late and v.lateness == 0.0


def test_a_single_hit_is_not_a_confirmation():
    hits = [True, False, False, False, False, True, False, False, False, False, False]
    v = late.judge(*approach(hits), EGO)
    assert v.late and math.isnan(v.detection_distance)


def test_time_to_collision_is_nan_when_not_closing():
    assert math.isnan(late.time_to_collision([5.0, 5.0, 5.0], [0.0, 0.2, 0.4], 1))
    assert math.isnan(late.time_to_collision([5.0, 6.0], [0.0, 0.2], 1))
    assert late.time_to_collision([6.0, 5.0], [0.0, 0.5], 1) == pytest.approx(2.5)


def test_trajectories_and_the_job_summary_from_a_frame_table():
    rows = []
    for label, hits, fair in (("early", [False, True, True, True, True, True, True, True, True], [True] * 9),
                              ("late", [False] * 7 + [True, True], [True] * 9),
                              ("hidden", [False] * 9, [False] * 9)):
        d, _, _, _ = approach(hits, fair)
        rows += [{"shot": len(rows) + k, "label": label, "distance": d[k], "composite": 0.8 if h else 0.1,
                  "fair": f} for k, (h, f) in enumerate(zip(hits, fair))]
    table = pd.DataFrame(rows)
    times = {r["shot"]: (12.0 - r["distance"]) / V for r in rows}
    per = late.trajectories(table, times, table.pop("fair"), EGO, threshold=0.5)
    assert list(per.label) == ["early", "late", "hidden"]
    assert list(per.testable) == [True, True, False] and list(per.late) == [False, True, False]
    s = late.summary(per, EGO)
    assert tuple(s) == late.METRICS  # what the sweep report reads of a job's run
    assert s["late"] == 0.5 and s["late_testable"] == 2 and s["late_trajectories"] == 1
    assert s["detection_distance"] == pytest.approx((10.0 + 4.0) / 2)  # over the confirmed trajectories
    assert "1 of 2 testable" in late.line(s)


def test_the_late_objective_prunes_an_untestable_trial_and_scores_lateness():
    base = {"visible_fraction_mean": 0.5, "fair_frames": 4, "frames": 10, "fair_difficulty": 0.3}
    done = outcome({**base, "late_testable": 1.0, "lateness": 0.4, "late": 0.0, "detection_distance": 7.0,
                    "ttc_at_detection": 2.5}, "late")
    assert done.state == TrialState.COMPLETE and done.values == [0.4]
    assert done.attrs["detection_distance"] == 7.0
    hidden = outcome({**base, "late_testable": 0.0, "lateness": math.nan, "late": math.nan}, "late")
    assert hidden.state == TrialState.PRUNED and hidden.attrs["infeasible"]
    # the difficulty objective is untouched by a late verdict beside it
    assert outcome({**base, "late_testable": 1.0, "lateness": 1.0, "late": 1.0}, "difficulty").values == [0.3]


def test_a_trial_line_is_worded_by_the_objective_not_by_its_values():
    """A difficulty search on a case that drives the ego returns a late verdict too: its line said "lateness"
    whenever the two numbers happened to be equal (issue 31, item 5)."""
    result = {"visible_fraction_mean": 0.5, "fair_frames": 4, "frames": 10, "fair_difficulty": 1.0,
              "late_testable": 1.0, "lateness": 1.0, "late": 1.0, "detection_distance": math.nan}
    hard = line(0, outcome(result, "difficulty"), 3, "difficulty")
    assert "difficulty 1.000 over 4 fair frame(s)" in hard and "lateness" not in hard
    late = line(1, outcome(result, "late"), 3, "late")
    assert late == "garage_exp: trial 1 (2 of 3): lateness 1.000 (late 1.00, never confirmed)"
    hidden = {**result, "fair_frames": 0, "fair_difficulty": math.nan, "late_testable": 0.0, "lateness": math.nan}
    assert line(2, outcome(hidden, "difficulty"), 3, "difficulty").endswith(
        "no fairly visible frame (visible fraction 0.50): infeasible")
    assert line(2, outcome(hidden, "late"), 3, "late").endswith(
        "never fairly visible before the critical distance: infeasible")


def test_stepout_frames_have_the_ego_time_and_the_child_steps_out_at_its_speed():
    from garage_exp.run.preflight import preflight

    cfg = compose_cfg("case=stepout", "ego.speed=18", "case.motion.along.child.at=10.0",
                      "case.motion.along.child.speed=3.0")
    shots = preflight(cfg, check_space=False).setup.shots
    v = 18 / 3.6
    assert [s.position for s in shots][:3] == [20.0, 19.5, 19.0]
    assert [s.time for s in shots][:3] == pytest.approx([0.0, 0.5 / v, 1.0 / v])
    child = cfg.case.actors.child
    before = [s for s in shots if s.position >= 10.0]
    after = [s for s in shots if s.position < 10.0]
    still = {(round(s.poses["child"].x, 6), round(s.poses["child"].y, 6)) for s in before}
    assert len(still) == 1, "the child waits between the cars until the ego is `at` metres away"
    first, later = after[0], after[2]
    moved = math.dist((first.poses["child"].x, first.poses["child"].y), (later.poses["child"].x, later.poses["child"].y))
    assert moved == pytest.approx(3.0 * (later.time - first.time), abs=1e-6)  # its running speed
    last = shots[-1].poses["child"]
    start = before[0].poses["child"]
    assert math.dist((start.x, start.y), (last.x, last.y)) == pytest.approx(
        cfg.case.motion.along.child.end - child.out, abs=1e-6)  # 3 m/s for 1.4 s would be 4.2 m: it stops where `end` puts it


def test_static_cases_have_no_times():
    from garage_exp.run.preflight import preflight

    shots = preflight(compose_cfg("case=2", "case.motion.step=5"), check_space=False).setup.shots
    assert {s.time for s in shots} == {0.0}


def test_the_sweep_report_tabulates_the_runs_whose_ego_moves():
    from garage_exp.report.tables import late_table

    runs = pd.DataFrame([{"run_name": "a", "late": 0.5, "late_testable": 2.0, "detection_distance": 6.0,
                          "ttc_at_detection": 2.1, "critical_distance": 5.0},
                         {"run_name": "b", "late": None, "late_testable": None}])
    table = late_table(runs)
    assert list(table["run"]) == ["a"] and table["late (share)"].tolist() == [0.5]
    assert late_table(pd.DataFrame([{"run_name": "static"}])).empty


def test_an_along_actor_takes_listed_values_and_a_person_its_place_in_the_gap():
    """What an adversary's exported episode says: the child's `out` frame by frame (held after the list), and
    `offset` along the gap (to the left of the child's heading into the lane)."""
    from garage_exp.run.preflight import preflight

    base = ["case=stepout", "case.motion.start=6", "case.motion.end=3", "case.motion.step=1.0"]
    listed = preflight(compose_cfg(*base, "case.motion.along.child.values=[0.0,0.5,1.0]",
                                   "case.actors.child.offset=0.3"), check_space=False).setup.shots
    plain = preflight(compose_cfg(*base, "case.motion.along.child.values=[0.0,0.5,1.0]"),
                      check_space=False).setup.shots
    outs = [math.dist((s.poses["child"].x, s.poses["child"].y), (listed[0].poses["child"].x,
                                                                listed[0].poses["child"].y)) for s in listed]
    assert outs == pytest.approx([0.0, 0.5, 1.0, 1.0])  # the list, then its last value held
    for a, b in zip(listed, plain):
        assert math.dist((a.poses["child"].x, a.poses["child"].y), (b.poses["child"].x, b.poses["child"].y)) \
            == pytest.approx(0.3)
