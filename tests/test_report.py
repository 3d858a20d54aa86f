"""The sweep report's tables, on hand-made run tables (no MLflow, no rendering)."""

import pandas as pd
import pytest

from garage_exp.report import breakdown, factors_of, main_effects, markdown, pair_effects


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
