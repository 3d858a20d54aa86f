"""What the loop's report says besides the failure rate (issue 50): whether every arm kept D0's recall on the
protocol suites and the real photos (loop/forgetting.py, recall_checks.csv), and the fine-tunings' validation
curves (loop/curves.py, validation.csv and validation.png). Synthetic tables and training logs: nothing rendered."""

from __future__ import annotations

import pandas as pd
import pytest

from tests.test_loop_paired import cfg_of, one_seed_scores


def with_protocol(scores: pd.DataFrame, recalls: dict[str, dict[str, float]]) -> pd.DataFrame:
    """The held-out scores plus protocol rows (suite -> arm -> fair recall) for D0 and round 1's arms."""
    rows = []
    for suite, by_arm in recalls.items():
        for arm, recall in by_arm.items():
            rows.append({"detector": arm, "arm": arm, "round": 0 if arm == "D0" else 1,
                         "seed": -1 if arm == "D0" else 0, "suite": suite, "fair_recall": recall})
    return pd.concat([scores, pd.DataFrame(rows)], ignore_index=True)


PHOTOS = [{"detector": a, "arm": a, "round": 0 if a == "D0" else 1, "seed": -1 if a == "D0" else 0, "set": "photos",
           "recall": r, "map50": 0.5} for a, r in (("D0", 0.90), ("R", 0.88), ("T", 0.80), ("Q", 0.95))]


def test_the_recall_checks_hold_each_arm_within_its_tolerance_of_d0():
    from garage_exp.loop import forgetting

    scores = with_protocol(one_seed_scores(), {
        "protocol:cpnco": {"D0": 0.50, "R": 0.49, "T": 0.50, "Q": 0.47},  # Q: 0.03 below, more than 0.02
        "protocol": {"D0": 0.60, "R": 0.62, "T": 0.59, "Q": 0.58}})
    checks = forgetting.recall_checks(scores, pd.DataFrame(PHOTOS), ["R", "T", "Q"], 1, 0.02, 0.05)
    held = {(r.arm, r.suite): r.holds for r in checks.itertuples()}
    assert held == {("R", "protocol"): True, ("T", "protocol"): True, ("Q", "protocol"): True,
                    ("R", "protocol:cpnco"): True, ("T", "protocol:cpnco"): True, ("Q", "protocol:cpnco"): False,
                    ("R", "real:photos"): True, ("T", "real:photos"): False, ("Q", "real:photos"): True}
    q = checks[(checks.arm == "Q") & (checks.suite == "protocol:cpnco")].iloc[0]
    assert (q.d0, q.recall, q.tolerance) == (0.50, 0.47, 0.02) and q["drop"] == pytest.approx(0.03)
    said = forgetting.sentence(checks)
    assert said.startswith("Not forgetting: R keeps D0's recall within the tolerance")
    assert "T forgets on 1 of 3 (worst real:photos: 0.80 vs D0 0.90" in said and "Q forgets on 1 of 3" in said


def test_a_suite_without_fair_frames_has_no_check_and_an_arm_without_recall_has_not_kept_it():
    from garage_exp.loop import forgetting

    nan = float("nan")
    scores = with_protocol(one_seed_scores(), {"protocol:crouch": {"D0": nan, "R": nan},
                                               "protocol:cpra": {"D0": 0.5, "R": nan}})
    checks = forgetting.recall_checks(scores, pd.DataFrame(), ["R"], 1, 0.02, 0.05)
    assert checks.suite.tolist() == ["protocol:cpra"] and checks.holds.tolist() == [False]


def test_a_failed_check_says_how_many_objects_it_lost_and_whether_its_suite_can_resolve_the_tolerance():
    """crossing's 4 fair frames move recall in steps of 0.25: one frame lost fails a 0.02 tolerance, and the
    sentence says "1 of 4"; a photo set of 32 targets lost 2; a table without counts (an older report) says none."""
    from garage_exp.loop import forgetting

    scores = with_protocol(one_seed_scores(), {"protocol:crossing": {"D0": 0.75, "R": 0.50, "T": 0.75, "Q": 1.0}})
    scores.loc[scores.suite == "protocol:crossing", "fair_frames"] = 4.0
    photos = pd.DataFrame([{**p, "set": "street", "recall": r, "objects": 32.0}
                           for p, r in zip(PHOTOS, (25 / 32, 23 / 32, 25 / 32, 26 / 32))])
    checks = forgetting.recall_checks(scores, photos, ["R", "T", "Q"], 1, 0.02, 0.05)
    row = {(r.arm, r.suite): r for r in checks.itertuples()}
    r = row[("R", "protocol:crossing")]
    assert (r.objects, r.step, r.lost, r.holds) == (4, 0.25, 1, False)
    assert row[("Q", "protocol:crossing")].lost == -1 and row[("Q", "protocol:crossing")].holds
    assert (row[("R", "real:street")].lost, row[("R", "real:street")].holds) == (2, False)
    said = forgetting.sentence(checks)
    assert "R forgets on 2 of 2 (worst protocol:crossing: 0.50 vs D0 0.75, allowed drop 0.02, 1 of 4 objects; " \
           "one object is more than the tolerance)" in said
    older = forgetting.recall_checks(scores, photos.drop(columns="objects"), ["R"], 1, 0.02, 0.05)
    street = older[older.suite == "real:street"].iloc[0]
    assert pd.isna(street.objects) and pd.isna(street.lost) and not street.holds
    assert "of 32 objects" not in forgetting.sentence(older[older.suite == "real:street"])


def test_the_report_writes_the_recall_checks_and_says_them(tmp_path):
    from garage_exp.loop import report

    scores = with_protocol(one_seed_scores(), {"protocol": {"D0": 0.60, "R": 0.60, "T": 0.60, "Q": 0.50}})
    summary = report.write(cfg_of([0]), tmp_path, scores, PHOTOS, [], {}, {})
    checks = pd.read_csv(tmp_path / "recall_checks.csv")
    assert len(checks) == 6 and checks.holds.sum() == 4  # Q forgets the protocol, T the photos
    assert summary["recall_checks_hold"] is False
    assert summary["not_forgetting"].startswith("Not forgetting: R keeps")
    md = (tmp_path / "report.md").read_text()
    assert summary["not_forgetting"] in md and "| arm | seed | suite | d0 | recall | drop |" in md
    # the tolerances come from the config when it has them
    loose = cfg_of([0])
    loose.forgetting = {"protocol_recall": 0.2, "photo_recall": 0.2}
    assert report.write(loose, tmp_path / "loose", scores, PHOTOS, [], {}, {})["recall_checks_hold"] is True


def results_csv(path, map50: list[float]):
    """A training log as ultralytics writes it (its header padded with spaces, as older versions do)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = [f"{e + 1},{0.1 * e:.1f},1.5,1.2,1.1,0.7,0.5,{m},0.2,{2.0 - 0.1 * e},1.5,1.4,0.0005,0.0005,0.0005"
            for e, m in enumerate(map50)]
    head = ("epoch,time,train/box_loss,train/cls_loss,train/dfl_loss,metrics/precision(B),metrics/recall(B),"
            "metrics/mAP50(B),metrics/mAP50-95(B),val/box_loss,val/cls_loss,val/dfl_loss,lr/pg0,lr/pg1,lr/pg2")
    path.write_text(",".join(f"  {c}" for c in head.split(",")) + "\n" + "\n".join(rows) + "\n")


def test_the_validation_curves_are_read_per_fine_tuning_and_say_which_still_rise(tmp_path):
    from garage_exp.loop import curves

    train = tmp_path / "train"
    results_csv(train / "R_r1_s0" / "ultralytics" / "results.csv", [0.30, 0.40, 0.42, 0.42])  # flattened
    results_csv(train / "Q_r1_s0" / "ultralytics" / "results.csv", [0.30, 0.35, 0.40, 0.46])  # still rising
    detectors = {"D0": {"arm": "D0", "round": 0, "seed": -1}, "R_r1_s0": {"arm": "R", "round": 1, "seed": 0},
                 "Q_r1_s0": {"arm": "Q", "round": 1, "seed": 0}}
    table = curves.read(train, detectors)
    assert sorted(table.detector.unique()) == ["Q_r1_s0", "R_r1_s0"]  # D0 as given was not fine-tuned here
    assert table[table.detector == "Q_r1_s0"].map50.tolist() == [0.30, 0.35, 0.40, 0.46]
    assert table.val_loss.iloc[0] == pytest.approx(2.0 + 1.5 + 1.4)
    flat = curves.converged(table)
    assert flat["R_r1_s0"] == {"epochs": 4, "best_epoch": 3, "best_map50": 0.42, "last_map50": 0.42,
                               "converged": True}
    assert flat["Q_r1_s0"]["converged"] is False and flat["Q_r1_s0"]["best_epoch"] == 4


def test_the_report_draws_the_validation_curves(tmp_path):
    from garage_exp.loop import curves, report

    results_csv(tmp_path / "train" / "R_r1_s0" / "ultralytics" / "results.csv", [0.2, 0.3, 0.305])
    table = curves.read(tmp_path / "train", {"R_r1_s0": {"arm": "R", "round": 1, "seed": 0}})
    summary = report.write(cfg_of([0]), tmp_path / "results", one_seed_scores(), [], [], {}, {}, curves=table)
    assert summary["validation"]["R_r1_s0"]["converged"] is True
    assert len(pd.read_csv(tmp_path / "results" / "validation.csv")) == 3
    from PIL import Image

    with Image.open(tmp_path / "results" / "validation.png") as png:
        assert png.size[0] > 600 and len(set(png.convert("L").getdata())) > 10  # two panels drawn, not blank
