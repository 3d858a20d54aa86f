"""The sweep report's slot section (issue 25) on hand-made slot tables: units pool their frames' counts, intervals
run over units, and the hardest factor is the one whose levels spread slot recall most."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from garage_exp.slots.report import hardest, pictures, section, slot_effects, slot_units
from garage_exp.report.tables import markdown_table, with_ci


def frame(run, rep, tp, fn, fp=0, ptp=0, pfn=0, pfp=0, right=0, n=0):
    return {"run_id": run, "replicate": rep, "slot_tp": tp, "slot_fn": fn, "slot_fp": fp, "point_tp": ptp,
            "point_fn": pfn, "point_fp": pfp, "occupancy_right": right, "occupancy_n": n}


def test_slot_units_pool_frames_and_effects_name_the_hardest_factor():
    runs = pd.DataFrame({"run_id": ["fresh_bright", "worn_bright", "fresh_dim", "worn_dim"],
                         "factor.wear": ["fresh", "worn", "fresh", "worn"],
                         "factor.light": ["bright", "bright", "dim", "dim"]})
    rows = []
    for run, (a, b) in {"fresh_bright": ((4, 0), (3, 1)), "worn_bright": ((1, 3), (0, 4)),
                        "fresh_dim": ((3, 1), (3, 1)), "worn_dim": ((1, 3), (1, 3))}.items():
        for rep, (tp, fn) in enumerate((a, b)):
            # two frames a replicate: the counts split over them pool back
            rows += [frame(run, rep, tp, 0, ptp=2 * tp, pfn=1, right=tp, n=tp + 1), frame(run, rep, 0, fn, fp=1)]
    obs = slot_units(runs, pd.DataFrame(rows), ["factor.wear", "factor.light"])
    assert len(obs) == 8  # a unit per run's replicate, not per frame
    one = obs[(obs.run_id == "fresh_bright") & (obs.replicate == 1)].iloc[0]
    assert one.slot_recall == pytest.approx(0.75) and one.slot_precision == pytest.approx(0.75)
    assert one.slot_point_recall == pytest.approx(6 / 7) and one.slot_occupancy_acc == pytest.approx(0.75)
    effects = slot_effects(obs, ["factor.wear", "factor.light"])
    wear = effects[effects.factor == "wear"].set_index("level")
    assert wear.loc["fresh", "slot_recall"] == pytest.approx((1.0 + 0.75 + 0.75 + 0.75) / 4)
    assert wear.loc["worn", "n"] == 4 and wear.loc["worn", "slot_recall_low"] <= wear.loc["worn", "slot_recall"]
    factor, level, spread = hardest(effects)
    assert (factor, level) == ("wear", "worn") and spread > 0.5
    text = "\n".join(section(effects, markdown_table, with_ci))
    assert "Hardest factor for slot recall: **wear**" in text and "light" in text


class Store:
    """The two calls `pictures` makes of an MLflow client, over runs whose frames are files in a folder."""

    def __init__(self, root):
        self.root = root

    def list_artifacts(self, run_id, path):
        from types import SimpleNamespace

        return [SimpleNamespace(path=f"frames/{p.name}") for p in sorted((self.root / run_id).glob("*.png"))]

    def download_artifacts(self, run_id, path, dst):
        return str(self.root / run_id / path.split("/")[-1])


def test_the_hardest_factor_is_shown_by_frames_of_its_best_and_worst_units(tmp_path):
    runs = pd.DataFrame({"run_id": ["a", "b", "c", "d"], "factor.wear": ["fresh", "fresh", "worn", "worn"]})
    rows = [frame("a", 0, 3, 1), frame("b", 0, 4, 0), frame("c", 0, 1, 3), frame("d", 0, 0, 4)]
    obs = slot_units(runs, pd.DataFrame(rows), ["factor.wear"])
    for run in "abcd":
        (tmp_path / run).mkdir()
        for shot in range(3):
            (tmp_path / run / f"{shot:04d}_bev.png").write_bytes(f"{run}{shot}".encode())
    out = tmp_path / "report"
    out.mkdir()
    text = "\n".join(pictures(Store(tmp_path), obs, slot_effects(obs, ["factor.wear"]), out))
    assert "wear=fresh" in text and "wear=worn" in text
    # the easiest fresh unit (b, recall 1) and the hardest worn one (d, recall 0), each its middle frame
    assert (out / "slots_wear_fresh.png").read_bytes() == b"b1" and (out / "slots_wear_worn.png").read_bytes() == b"d1"
    assert "](slots_wear_worn.png)" in text and "slot recall 0.00" in text


def test_levels_that_find_slots_alike_name_no_hardest_factor_and_show_no_frames(tmp_path):
    """Seen on a tiny-plan sweep where both wear levels found nothing: no factor is named, no frame shown twice."""
    runs = pd.DataFrame({"run_id": ["a", "b"], "factor.wear": ["fresh", "worn"]})
    obs = slot_units(runs, pd.DataFrame([frame("a", 0, 0, 4), frame("b", 0, 0, 4)]), ["factor.wear"])
    effects = slot_effects(obs, ["factor.wear"])
    assert hardest(effects) is None
    assert pictures(Store(tmp_path), obs, effects, tmp_path) == []
    assert "Hardest factor" not in "\n".join(section(effects, markdown_table, with_ci))


def test_no_scored_slots_no_section():
    runs = pd.DataFrame({"run_id": ["a"], "factor.light": ["dim"]})
    truth_only = pd.DataFrame([{"run_id": "a", "shot": 0, "slots": 5, "fair": 3}])  # no detector: no counts
    assert slot_units(runs, truth_only, ["factor.light"]).empty
    assert section(pd.DataFrame(), markdown_table, with_ci) == []
    unscored = slot_units(runs, pd.DataFrame([frame("a", 0, 0, 0)]), ["factor.light"])
    assert math.isnan(unscored.slot_recall.iloc[0]) and hardest(slot_effects(unscored, ["factor.light"])) is None


def test_the_slots_search_objective_ranks_by_missed_fair_slots():
    from optuna.trial import TrialState

    from garage_exp.search.loop import line, outcome

    summary = {"fair_frames": 0.0, "fair_difficulty": float("nan"), "frames": 4.0, "run_id": "r", "output_dir": "/x",
               "slot_recall": 0.25, "slot_precision": 0.5, "slot_truth_fair": 3.0}
    out = outcome(summary, "slots")  # the object target's visibility does not matter to the slot objective
    assert out.state == TrialState.COMPLETE and out.values == [0.75] and out.attrs["slot_precision"] == 0.5
    none_fair = outcome({**summary, "slot_recall": float("nan"), "slot_truth_fair": 0.0}, "slots")
    assert none_fair.state == TrialState.PRUNED and none_fair.attrs["infeasible"] is True
    assert "slot_miss 0.750 (slot recall 0.250, 3.0 fair slots a frame)" in line(0, out, 4, "slots")
    assert "no fair slot" in line(1, none_fair, 4, "slots")


def test_the_slots_objective_needs_a_slot_case_on_fisheye_cameras():
    from conftest import compose_cfg

    from garage_exp.core.errors import GarageError
    from garage_exp.search.sweep import _check_objective

    cfg = compose_cfg("case=slots", "camera=fisheye4", "search.objective=slots")
    _check_objective(cfg.search, cfg)
    with pytest.raises(GarageError, match="slot case on a fisheye rig"):
        _check_objective(cfg.search, compose_cfg("case=slots", "search.objective=slots"))
