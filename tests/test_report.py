"""The sweep report's tables, on hand-made run tables (no MLflow, no rendering)."""

import pandas as pd
import pytest

from garage_exp.report import breakdown, factors_of, main_effects, markdown, pair_effects, summary


@pytest.fixture
def runs():
    rows = []
    for light, base in (("bright", 0.8), ("dim", 0.6)):
        for blank, bonus in (("False", 0.0), ("True", 0.1)):
            conf = base + bonus
            rows.append({"run_id": f"{light}{blank}", "run_name": f"light={light} blank={blank}",
                         "status": "FINISHED", "skipped": False, "error": "", "factor.light": light,
                         "factor.blank": blank, "factor.seed": "0", "confidence_mean": conf, "recall": conf,
                         "difficulty": 1 - conf, "label.black": conf + 0.05, "label.white": conf - 0.05,
                         "model.yolo11n_int8": conf - 0.1})
    return pd.DataFrame(rows)


def test_only_swept_factors_count(runs):
    assert factors_of(runs) == ["factor.light", "factor.blank"]


def test_main_effects_average_over_the_other_factors(runs):
    effects = main_effects(runs, factors_of(runs)).set_index(["factor", "level"])
    assert effects.loc[("light", "bright"), "confidence_mean"] == pytest.approx(0.85)
    assert effects.loc[("blank", "True"), "confidence_mean"] == pytest.approx(0.8)
    pairs = pair_effects(runs, factors_of(runs))
    assert len(pairs) == 4 and set(pairs.pair) == {"light x blank"}


def test_breakdown_is_the_research_table_shape(runs):
    table = breakdown(runs, factors_of(runs), "label.")
    assert list(table.index) == ["black", "white"]
    assert list(table.columns) == ["light=bright, blank=False", "light=bright, blank=True",
                                   "light=dim, blank=False", "light=dim, blank=True"]
    assert table.loc["black", "light=dim, blank=True"] == pytest.approx(0.75)
    assert table.loc["white", "light=bright, blank=False"] == pytest.approx(0.75)
    models = breakdown(runs, factors_of(runs), "model.")
    assert list(models.index) == ["yolo11n_int8"]


def test_breakdown_without_metrics_or_factors(runs):
    assert breakdown(runs.drop(columns=["label.black", "label.white"]), ["factor.light"], "label.").empty
    single = breakdown(runs.iloc[:1], [], "label.")
    assert single.loc["black", "confidence"] == pytest.approx(0.85)


def test_markdown_holds_every_section(runs):
    text = markdown(runs, main_effects(runs, factors_of(runs)), pair_effects(runs, factors_of(runs)),
                    {"Per label": breakdown(runs, factors_of(runs), "label.")})
    for heading in ("## Main effects", "## Pairs", "## Runs ranked by difficulty", "## Per label"):
        assert heading in text
    assert "| what | light=bright, blank=False |" in text


def test_main_and_pair_effects_values(runs):
    effects = main_effects(runs, factors_of(runs))
    assert list(effects.columns) == ["factor", "level", "confidence_mean", "recall", "difficulty"]
    by = effects.set_index(["factor", "level"])
    assert by.loc[("light", "dim"), "confidence_mean"] == pytest.approx(0.65)
    assert by.loc[("light", "dim"), "difficulty"] == pytest.approx(0.35)
    assert by.loc[("blank", "False"), "recall"] == pytest.approx(0.7)
    pairs = pair_effects(runs, factors_of(runs)).set_index(["level_a", "level_b"])
    assert list(pairs.columns) == ["pair", "confidence_mean", "recall"]
    assert pairs.loc[("dim", "True"), "confidence_mean"] == pytest.approx(0.7)
    assert pairs.loc[("bright", "False"), "recall"] == pytest.approx(0.8)
    assert main_effects(runs, []).empty and pair_effects(runs, ["factor.light"]).empty


def test_factors_of_ignores_unswept_and_missing_levels(runs):
    runs = runs.assign(**{"factor.case": ["1", "1", None, "1"], "other": ["a", "b", "c", "d"]})
    assert factors_of(runs) == ["factor.light", "factor.blank"]  # one level (NaN aside) is no factor


def test_summary_counts_and_lists_failures(runs):
    runs = runs.copy()
    runs.loc[1, ["status", "error"]] = ["FAILED", "RuntimeError: boom"]
    runs.loc[2, "skipped"] = True
    text, bad = summary(runs)
    lines = text.splitlines()
    assert lines[0] == "garage_exp: sweep summary: 4 jobs: 2 finished, 1 skipped (finished before), 1 failed"
    assert lines[1:] == ["  FAILED: light=bright blank=True (run brightTrue): RuntimeError: boom"]
    assert bad == 1
    text, bad = summary(runs, expected=6)
    assert text.splitlines()[0].endswith("1 failed, 2 without a run") and bad == 3
    text, bad = summary(runs.iloc[0:0], expected=2)
    assert text == "garage_exp: sweep summary: 2 jobs: 0 finished, 0 skipped (finished before), 0 failed, " \
                   "2 without a run" and bad == 2
    quiet, bad = summary(runs.drop(columns=["skipped"]).iloc[[0, 3]])
    assert quiet == "garage_exp: sweep summary: 2 jobs: 2 finished, 0 skipped (finished before), 0 failed"
    assert bad == 0
    runs.loc[1, "error"] = ""
    assert summary(runs)[0].splitlines()[1].endswith("no error recorded")


def test_breakdown_averages_repeats_and_drops_missing(runs):
    twice = pd.concat([runs, runs.assign(**{"label.black": runs["label.black"] + 0.1})], ignore_index=True)
    table = breakdown(twice, ["factor.light"], "label.")
    assert list(table.columns) == ["light=bright", "light=dim"]
    assert table.loc["black", "light=bright"] == pytest.approx((0.85 + 0.95) / 2 + 0.05)
    gaps = runs.assign(**{"label.white": [None] * 4})
    assert list(breakdown(gaps, ["factor.light"], "label.").index) == ["black"]


def test_tables_keep_the_sweep_order_and_their_column_order():
    rows = [{"run_id": str(k), "run_name": "", "status": "FINISHED", "skipped": False, "error": "",
             "factor.light": light, "factor.case": case, "confidence_mean": c, "recall": c, "difficulty": 1 - c,
             "label.white": c, "label.black": c / 2}
            for k, (light, case, c) in enumerate([("dim", "2", 0.2), ("dim", "1", 0.4), ("bright", "2", 0.6),
                                                  ("bright", "1", 0.8)])]
    runs = pd.DataFrame(rows)
    factors = factors_of(runs)
    pairs = pair_effects(runs, factors)
    assert list(pairs.columns) == ["pair", "level_a", "level_b", "confidence_mean", "recall"]
    assert list(pairs.index) == [0, 1, 2, 3]
    effects = main_effects(runs, factors)
    assert list(effects.index) == [0, 1, 2, 3]  # one table, renumbered (not 0, 1 per factor)
    table = breakdown(runs, factors, "label.")
    assert list(table.columns) == ["light=dim, case=2", "light=dim, case=1", "light=bright, case=2",
                                   "light=bright, case=1"]  # the sweep's order, not sorted
    assert table.loc["white", "light=dim, case=2"] == pytest.approx(0.2)
    assert breakdown(runs.iloc[0:0], factors, "label.").empty


def test_summary_without_runs_or_expectation_and_long_errors(runs):
    text, bad = summary(runs.iloc[0:0])
    assert text == "garage_exp: sweep summary: 0 jobs: 0 finished, 0 skipped (finished before), 0 failed"
    assert bad == 0
    failed = runs.copy()
    failed.loc[0, ["status", "error"]] = ["FAILED", "x" * 1000]
    line = summary(failed)[0].splitlines()[1]
    assert len(line) == 600 and line.endswith("x")
