"""The sweep report's tables, intervals and tests, on hand-made run and frame tables (no MLflow, no rendering)."""

import math

import numpy as np
import pandas as pd
import pytest

from garage_exp.results import stats
from garage_exp.report import markdown
from garage_exp.report import visibility as vis
from garage_exp.report.tables import (breakdown, factors_of, main_effects, pair_effects, pivot, significance,
                                      summary, units)

LIGHTS = {"bright": 0.8, "dim": 0.5}
BLANKS = {"False": 0.0, "True": 0.1}


@pytest.fixture
def runs():
    rows = []
    for light, base in LIGHTS.items():
        for blank, bonus in BLANKS.items():
            conf = base + bonus
            rows.append({"run_id": f"{light}{blank}", "run_name": f"light={light} blank={blank}",
                         "status": "FINISHED", "skipped": False, "error": "", "threshold": 0.5,
                         "factor.light": light, "factor.blank": blank, "factor.seed": "0", "confidence_mean": conf,
                         "recall": conf, "difficulty": 1 - conf})
    return pd.DataFrame(rows)


def frames_for(runs, replicates=4, noise=0.05, seed=0):
    """Frame tables: per run and replicate, a black and a white trajectory of 3 frames each; the replicate adds
    a shift shared by its frames (the reason frames are not independent units)."""
    rng = np.random.default_rng(seed)
    rows = []
    for _, r in runs.iterrows():
        for k in range(replicates):
            shift = rng.normal(0, noise)
            for label, d in (("black", 0.05), ("white", -0.05)):
                for pos in range(3):
                    c = float(np.clip(r.confidence_mean + d + shift, 0, 1))
                    vf = [0.1, 0.5, 0.9][pos]
                    rows.append({"run_id": r.run_id, "shot": pos, "replicate": k, "label": label, "position": pos,
                                 "camera": "front", "visible_fraction": vf,
                                 "kitti": ["ignored", "hard", "easy"][pos], "conf_yolo11n": c - 0.1,
                                 "conf_yolov8n": c + 0.1, "composite": c})
    return pd.DataFrame(rows)


def test_only_swept_factors_count(runs):
    assert factors_of(runs) == ["factor.light", "factor.blank"]


def test_units_are_a_runs_replicates_not_its_frames(runs):
    frames = frames_for(runs, replicates=3)
    obs = units(runs, frames, factors_of(runs))
    assert len(obs) == 4 * 3 and set(obs.replicate) == {0, 1, 2}
    one = frames[(frames.run_id == "dimTrue") & (frames.replicate == 1)]
    row = obs[(obs.run_id == "dimTrue") & (obs.replicate == 1)].iloc[0]
    assert row.confidence_mean == pytest.approx(one.composite.mean())
    assert row.recall == pytest.approx((one.composite >= 0.5).mean())
    assert row.difficulty == pytest.approx(1 - row.confidence_mean)
    # A run without a frame table (a dry run's, an old run's) is one unit from its metrics; a failed run none.
    runs.loc[3, "status"] = "FAILED"
    obs = units(runs, frames[frames.run_id != "brightFalse"], factors_of(runs))
    assert len(obs) == 2 * 3 + 1
    assert obs[obs.run_id == "brightFalse"].confidence_mean.tolist() == [pytest.approx(0.8)]
    assert "dimTrue" not in set(obs.run_id)


def test_other_cameras_do_not_enter_the_units(runs):
    frames = frames_for(runs, replicates=2)
    rear = frames.assign(camera="rear", composite=0.0)
    obs = units(runs, pd.concat([frames, rear]), factors_of(runs))
    assert obs.confidence_mean.min() > 0.3  # the rear camera's zeros are not averaged in


def test_main_effects_carry_intervals_over_units(runs):
    obs = units(runs, frames_for(runs, replicates=5), factors_of(runs))
    effects = main_effects(obs, factors_of(runs))
    assert list(effects.columns) == ["factor", "level", "n", "confidence_mean", "confidence_mean_low",
                                     "confidence_mean_high", "recall", "recall_low", "recall_high", "difficulty",
                                     "difficulty_low", "difficulty_high"]
    by = effects.set_index(["factor", "level"])
    assert by.loc[("light", "bright"), "n"] == 10  # 2 blank levels x 5 replicates
    assert by.loc[("light", "bright"), "confidence_mean"] == pytest.approx(0.85, abs=0.03)
    assert by.loc[("light", "dim"), "confidence_mean"] == pytest.approx(0.55, abs=0.03)
    for _, r in effects.iterrows():
        assert r.confidence_mean_low <= r.confidence_mean <= r.confidence_mean_high
        assert r.confidence_mean_high - r.confidence_mean_low > 0
    assert by.loc[("light", "dim"), "difficulty"] == pytest.approx(1 - by.loc[("light", "dim"), "confidence_mean"])
    assert list(effects.index) == [0, 1, 2, 3]  # one table, renumbered, in the sweep's order of levels
    assert list(effects.level) == ["bright", "dim", "False", "True"]


def test_pair_cells_with_one_unit_have_no_interval(runs):
    obs = units(runs, pd.DataFrame(), factors_of(runs))  # no frames: one unit per run
    pairs = pair_effects(obs, factors_of(runs)).set_index(["level_a", "level_b"])
    assert pairs.loc[("dim", "True"), "confidence_mean"] == pytest.approx(0.6)
    assert pairs.loc[("dim", "True"), "n"] == 1 and math.isnan(pairs.loc[("dim", "True"), "confidence_mean_low"])
    assert main_effects(obs, []).empty and pair_effects(obs, ["factor.light"]).empty


def test_anova_finds_the_real_effect_and_not_the_null_ones(runs):
    """Light matters, blank does not, and they do not interact: over 20 simulated sweeps the real effect is
    always found and the null ones about as often as the 5 % level allows."""
    runs = runs.assign(confidence_mean=[0.8, 0.8, 0.5, 0.5])
    found = {"light": 0, "blank": 0, "light x blank": 0}
    for seed in range(20):
        obs = units(runs, frames_for(runs, replicates=6, noise=0.03, seed=seed), factors_of(runs))
        table = significance(obs, factors_of(runs))
        conf = table[table.response == "confidence_mean"].set_index("term")
        assert list(conf.index) == ["light", "blank", "replicate", "light x blank"]
        assert ((conf.partial_eta2 >= 0) & (conf.partial_eta2 <= 1)).all() and (conf.units == 24).all()
        assert conf.loc["light", "partial_eta2"] > 0.9
        for term in found:
            found[term] += conf.loc[term, "significant"] == "yes"
    assert found["light"] == 20
    assert found["blank"] <= 3 and found["light x blank"] <= 3


def test_anova_without_replicates_drops_the_interaction_it_cannot_test(runs):
    """2 x 2 cells, one unit each: saturated with a x b, so the interaction is left out and is the error term;
    the report says that the test then assumes no interaction (issue 42, item 8)."""
    runs = runs.assign(confidence_mean=[0.8, 0.75, 0.6, 0.45], recall=[0.8, 0.75, 0.6, 0.45])  # not additive
    obs = units(runs, pd.DataFrame(), factors_of(runs))
    table = significance(obs, factors_of(runs))
    assert set(table.term) == {"light", "blank"} and (table.significant != "-").all()
    assert "the test assumes the factors do not interact" in table.attrs["notes"]["confidence_mean"]
    one = runs.iloc[:1]
    assert significance(units(one, pd.DataFrame(), []), []).empty


def test_anova_of_an_exact_fit_or_a_constant_response_prints_no_p_value(runs):
    """A 2 x 2 sweep of one replicate whose responses add up exactly (the fixture's: light + blank) leaves a
    residual of zero: statsmodels says F = 1e30, p = 0.000, and the report said "significant". There is no
    error to test against: no rows, the reason, no p-value (issue 42, item 8). The same for a response that is
    the same in every unit (statsmodels gave F = 0.014, p = 0.93 from rounding noise) and for a model with no
    residual degrees of freedom."""
    factors = factors_of(runs)
    obs = units(runs, pd.DataFrame(), factors)
    assert stats.anova(obs, factors, "confidence_mean", block="replicate").empty
    table = significance(obs, factors)
    assert table.empty and set(table.attrs["untestable"]) == {"confidence_mean", "recall"}
    assert "fits every unit exactly (zero residual variance)" in table.attrs["untestable"]["recall"]
    text = markdown(runs, obs, main_effects(obs, factors), pair_effects(obs, factors), table)
    section = text.split("## Significance")[1].split("## Pairs")[0]
    assert "recall: not testable: the model fits every unit exactly" in section
    assert "| yes |" not in section and "1e+30" not in section and "0.000" not in section, section
    flat = units(runs.assign(recall=1.0), frames_for(runs.assign(recall=1.0), replicates=3), factors)
    flat["recall"] = 1.0  # every trajectory detected: nothing varies
    assert "recall is 1 in every unit" in significance(flat, factors).attrs["untestable"]["recall"]
    assert set(significance(flat, factors).response) == {"confidence_mean"}  # the other response is tested
    assert "no residual degrees of freedom" in stats.anova(
        obs.assign(replicate=[0, 1, 2, 3]), factors, "confidence_mean", block="replicate").attrs["untestable"]


def test_breakdowns_per_label_and_model_with_intervals(runs):
    frames = frames_for(runs, replicates=3)
    labels = breakdown(frames, runs, factors_of(runs), "label")
    assert set(labels.what) == {"black", "white"} and (labels.n == 3).all()
    table = pivot(labels)
    assert list(table.columns) == ["light=bright, blank=False", "light=bright, blank=True",
                                   "light=dim, blank=False", "light=dim, blank=True"]
    assert table.loc["black", "light=dim, blank=True"].startswith("0.6")
    assert "[" in table.loc["black", "light=dim, blank=True"]
    models = breakdown(frames, runs, factors_of(runs), "model")
    assert set(models.what) == {"yolo11n", "yolov8n"}
    assert breakdown(frames, runs, factors_of(runs), "kind").empty  # no people in these scenes
    assert breakdown(pd.DataFrame(), runs, factors_of(runs), "label").empty


def test_markdown_prints_intervals_and_dashes_never_nan(runs):
    frames = frames_for(runs, replicates=3)
    factors = factors_of(runs)
    obs = units(runs, frames, factors)
    text = markdown(runs, obs, main_effects(obs, factors), pair_effects(obs, factors), significance(obs, factors),
                    {"Per label": breakdown(frames, runs, factors, "label")}, vis.by_bins(frames, runs),
                    vis.curves(frames, runs))
    for heading in ("## Main effects", "## Significance", "## Pairs", "## Runs ranked by difficulty",
                    "## Per label", "## Detection against visibility", "## Visible fraction at which recall"):
        assert heading in text
    assert "nan" not in text.lower().replace("nanos", "")
    assert "| light | bright | 6 | 0.8" in text and " [0." in text
    alone = units(runs, pd.DataFrame(), factors)
    text = markdown(runs, alone, main_effects(alone, factors), pair_effects(alone, factors),
                    significance(alone, factors))
    assert "0.600 [-]" in text  # one unit: a mean without an interval


def test_mean_ci_covers_the_true_mean_about_95_percent_of_the_time():
    rng = np.random.default_rng(1)
    hits = 0
    for trial in range(80):
        _, lo, hi = stats.mean_ci(rng.normal(0.5, 0.1, size=25), seed=trial)
        hits += lo <= 0.5 <= hi
    assert 68 <= hits <= 80  # 95 % nominal; percentile bootstrap runs a little narrow at n = 25
    assert math.isnan(stats.mean_ci([0.4])[1]) and stats.mean_ci([0.3, 0.3])[1:] == (0.3, 0.3)
    assert math.isnan(stats.mean_ci([])[0])


def test_cluster_interval_is_wider_than_pretending_frames_are_independent():
    rng = np.random.default_rng(2)
    clusters = np.repeat(np.arange(6), 20)
    values = np.repeat(rng.uniform(0, 1, 6), 20)  # frames of a trajectory move together
    mean, lo, hi, n = stats.ratio_ci(values, clusters)
    _, flo, fhi, _ = stats.ratio_ci(values, np.arange(len(values)))
    assert n == 6 and lo <= mean <= hi
    assert (hi - lo) > 3 * (fhi - flo)


def test_recall_curve_recovers_a_known_crossing():
    rng = np.random.default_rng(3)
    vf = rng.uniform(0, 1, 600)
    p = 1 / (1 + np.exp(-12 * (vf - 0.4)))
    frames = pd.DataFrame({"hit": (rng.uniform(size=600) < p).astype(float), "visible_fraction": vf,
                           "trajectory": np.repeat(np.arange(60), 10)})
    fit = stats.recall_curve(frames, "hit", 0.5)
    assert fit["v50_low"] <= 0.4 <= fit["v50_high"] and abs(fit["v50"] - 0.4) < 0.05 and fit["slope"] > 5
    flat = frames.assign(hit=1.0)
    assert math.isnan(stats.recall_curve(flat, "hit", 0.5)["v50"])  # always detected: no crossing
    seen = frames.assign(visible_fraction=0.9 + 0.1 * frames.visible_fraction)
    assert math.isnan(stats.recall_curve(seen, "hit", 0.5)["v50"])  # all unoccluded: no curve to fit
    assert vis.reading(0.4) == "" and "below 0.5" in vis.reading(1.06) and "no fit" in vis.reading(math.nan)


def test_visibility_bins_per_model_and_level(runs):
    frames = frames_for(runs, replicates=2)
    bins = vis.by_bins(frames, runs)
    assert set(bins.model) == {"yolo11n", "yolov8n", "composite"}
    comp = bins[(bins.model == "composite") & (bins.by == "visible fraction")].set_index("bin")
    assert list(comp.index) == ["reasonable (>= 0.65)", "heavy (0.2-0.65)", "< 0.2"]
    assert (comp.frames == 4 * 2 * 2).all() and (comp.trajectories == 16).all()
    kitti = bins[(bins.model == "composite") & (bins.by == "KITTI level")].set_index("bin")
    assert kitti.loc["easy", "frames"] == 16 and kitti.loc["moderate", "frames"] == 0
    assert math.isnan(kitti.loc["moderate", "recall"])
    hard = frames.assign(composite=np.where(frames.visible_fraction < 0.65, 0.0, 0.9))
    ratio = vis.miss_rate_ratio(vis.by_bins(hard, runs))
    assert math.isnan(ratio)  # no miss among reasonable frames: the ratio is undefined, not infinite
    some = hard.assign(composite=np.where((hard.visible_fraction > 0.65) & (hard.replicate == 0)
                                          & (hard.label == "black"), 0.0, hard.composite))
    assert vis.miss_rate_ratio(vis.by_bins(some, runs)) == pytest.approx(1.0 / 0.25)


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


def test_summary_without_runs_or_expectation_and_long_errors(runs):
    text, bad = summary(runs.iloc[0:0])
    assert text == "garage_exp: sweep summary: 0 jobs: 0 finished, 0 skipped (finished before), 0 failed"
    assert bad == 0
    failed = runs.copy()
    failed.loc[0, ["status", "error"]] = ["FAILED", "x" * 1000]
    line = summary(failed)[0].splitlines()[1]
    assert len(line) == 600 and line.endswith("x")


def test_a_sweep_without_confidences_still_reports(runs):
    """A dry-run sweep: finished runs, no metrics, no frames. Every table is empty, and the text says so."""
    dry = runs.assign(confidence_mean=None, recall=None, difficulty=None)
    factors = factors_of(dry)
    obs = units(dry, pd.DataFrame(), factors)
    effects, pairs = main_effects(obs, factors), pair_effects(obs, factors)
    assert obs.empty and effects.empty and pairs.empty
    text = markdown(dry, obs, effects, pairs, significance(obs, factors))
    assert "0 units" in text and "(none)" in text
