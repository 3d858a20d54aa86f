"""The loop's comparison paired by held-out scenario (issue 50): every detector scores the same rendered held-out
frames, so each scenario is a pair of outcomes; McNemar's exact test on the discordant scenarios, Newcombe's
paired interval of the difference, Holm over a round's comparisons; the report writes paired_scenarios.csv and,
with one training seed, its verdict rests on this test (the seed-paired one has no test there). Synthetic tables:
nothing is rendered."""

from __future__ import annotations

import math

import pandas as pd
import pytest


def failed_sets(both: int, a_only: int, b_only: int, neither: int) -> tuple[list[int], list[int], int]:
    """Scenario numbers each of two detectors failed, from the 2x2 table of pairs."""
    a = list(range(both + a_only))
    b = list(range(both)) + list(range(both + a_only, both + a_only + b_only))
    return a, b, both + a_only + b_only + neither


def test_the_paired_test_on_a_known_table():
    """McNemar's exact p-value is the two-sided binomial test of the discordant pairs: 6 against 1 gives
    2 (1 + 7) / 2^7 = 0.125, and 1 against 7 gives 2 (1 + 8) / 2^8. With uncorrelated pairs (ad = bc: phi 0)
    Newcombe's paired interval is his interval for independent samples, statsmodels' `newcomb`."""
    from statsmodels.stats.proportion import confint_proportions_2indep

    from garage_exp.loop import stats

    a, b, n = failed_sets(both=2, a_only=6, b_only=1, neither=3)  # ad = 6 = bc
    got = stats.paired_scenarios(a, b, n)
    assert (got["both"], got["a_only"], got["b_only"], got["neither"]) == (2, 6, 1, 3)
    assert got["p"] == pytest.approx(0.125)
    assert got["diff"] == pytest.approx(100 * 5 / 12) and got["relative"] == pytest.approx((8 - 3) / 3)
    low, high = confint_proportions_2indep(8, 12, 3, 12, method="newcomb", compare="diff")
    assert (got["low"], got["high"]) == pytest.approx((100 * low, 100 * high), abs=1e-9)
    a, b, n = failed_sets(both=1, a_only=1, b_only=7, neither=12)
    got = stats.paired_scenarios(a, b, n)
    assert got["p"] == pytest.approx(18 / 256) and got["diff"] == pytest.approx(-600 / 21)
    # positively correlated pairs (most scenarios failed by both or neither): narrower than independent samples,
    # here excluding 0 where the independent samples' interval does not
    a, b, n = failed_sets(both=40, a_only=12, b_only=2, neither=146)
    got = stats.paired_scenarios(a, b, n)
    low, high = confint_proportions_2indep(52, 200, 42, 200, method="newcomb", compare="diff")
    assert got["diff"] == pytest.approx(5.0) and 100 * low < 0 < got["low"] < got["high"] < 100 * high
    assert got["p"] == pytest.approx(2 * sum(math.comb(14, i) for i in range(3)) / 2 ** 14)
    with pytest.raises(ValueError, match="not the same held-out sample"):
        stats.paired_scenarios([0, 1, 2], [3], 3)


def test_identical_detectors_give_p_1_and_an_interval_around_0():
    from garage_exp.loop import stats

    got = stats.paired_scenarios([3, 5, 8], [8, 5, 3], 40)
    assert got["p"] == 1.0 and got["diff"] == 0.0 and got["a_only"] == got["b_only"] == 0
    assert got["low"] < 0 < got["high"] and got["low"] == pytest.approx(-got["high"])
    assert stats.paired_scenarios([], [], 10)["p"] == 1.0


def test_the_paired_power_needs_fewer_scenarios_when_detectors_agree():
    """Connor's (1987) McNemar sample size against his formula, and below the independent samples' bound."""
    from scipy.stats import norm

    from garage_exp.loop import stats

    for rate, discordant, m in ((0.5, 0.2, 1), (0.56, 0.3, 12)):
        d = 0.2 * rate
        za, zb = norm.ppf(1 - 0.05 / m / 2), norm.ppf(0.8)
        n = (za * math.sqrt(discordant) + zb * math.sqrt(discordant - d * d)) ** 2 / d ** 2
        assert stats.scenarios_for_paired(rate, discordant, 0.2, m) == math.ceil(n) < stats.scenarios_for(rate, 0.2, m)
    with pytest.raises(ValueError, match="discordant share"):
        stats.scenarios_for_paired(0.5, 0.05)  # fewer discordant scenarios than the difference: impossible


def one_seed_scores(n: int = 200) -> pd.DataFrame:
    """D0 and round 1's R, T and Q at one seed on n held-out scenarios: Q fails 30 of them (R's 60 less 32 it
    fixed plus 2 new), T 56 (6 fixed, 2 new), D0 70."""
    r = list(range(60))
    failed = {"D0": list(range(70)), "R": r, "T": r[6:] + [100, 101], "Q": r[32:] + [100, 101]}
    rows = []
    for arm, f in failed.items():
        rows.append({"detector": arm, "arm": arm, "round": 0 if arm == "D0" else 1, "seed": -1 if arm == "D0" else 0,
                     "suite": "heldout", "failures": len(f), "scenarios": n, "per_100": 100 * len(f) / n,
                     "failed": f, "fair_recall": 0.5})
    return pd.DataFrame(rows)


def cfg_of(seeds):
    from omegaconf import OmegaConf

    return OmegaConf.create({"arms": {"R": {"sampler": "random"}, "T": {"sampler": "tpe"},
                                      "Q": {"sampler": "archive"}}, "rounds": 1, "seeds": seeds})


def test_the_report_writes_the_paired_table_and_its_verdict_uses_it_with_one_seed(tmp_path):
    from garage_exp.loop import report, stats

    scores = one_seed_scores()
    summary = report.write(cfg_of([0]), tmp_path, scores, [], [], {}, {})
    table = pd.read_csv(tmp_path / "paired_scenarios.csv")
    assert list(zip(table.a, table.b)) == [("T", "R"), ("Q", "R"), ("Q", "T"), ("R", "D0"), ("T", "D0"),
                                           ("Q", "D0")]
    q = table[(table.a == "Q") & (table.b == "R")].iloc[0]
    assert (q.a_only, q.b_only, q["diff"], q.relative) == (2, 32, -15.0, -0.5)
    assert q.p == pytest.approx(stats.paired_scenarios(scores.failed[3], scores.failed[1], 200)["p"])
    assert table.p_holm.tolist() == pytest.approx(stats.holm(table.p.tolist())[1])  # one round: one family
    # the seed-paired comparisons have no test at one seed; the verdict rests on the scenarios' pairs
    assert pd.read_csv(tmp_path / "comparisons.csv").p.isna().all()
    sentence = summary["verdict"]
    assert sentence.startswith("After round 1, Q beats R (paired by held-out scenario, 200 scenarios, one seed)")
    assert "T 28.0 vs R 30.0 per 100 (relative -7 %" in sentence  # T: fewer failures, not 20 % fewer
    estimate = summary["power"]  # McNemar's scenarios from the run's most discordant pair of arms (Q-T: 26 of 200)
    assert estimate["discordant_share"]["Q-T"] == 0.13
    assert estimate["scenarios_needed_20pct_holm_paired"] == stats.scenarios_for_paired(0.35, 0.17, 0.2, 6)
    md = (tmp_path / "report.md").read_text()
    assert md.startswith(sentence) and "| round | seed | a | b |" in md and "| Q | R |" in md


def test_several_seeds_are_compared_per_seed_and_the_verdict_keeps_the_seed_paired_test(tmp_path):
    from garage_exp.loop import report

    first = one_seed_scores()
    second = first[first.arm != "D0"].assign(seed=1)
    summary = report.write(cfg_of([0, 1]), tmp_path, pd.concat([first, second], ignore_index=True), [], [], {}, {})
    table = pd.read_csv(tmp_path / "paired_scenarios.csv")
    assert sorted(table.seed.unique()) == [0, 1] and len(table) == 12  # per seed, never pooled
    # the same difference at both seeds: the seed-paired test has no spread, so no test, and nothing is decided
    assert summary["verdict"].startswith("After round 1, no targeted arm fails at least 20 % less often than R")
    assert "(paired by training seed, 2 seeds)" in summary["verdict"] and "Holm p no test" in summary["verdict"]


def test_the_estimate_adds_the_paired_power_when_a_pilot_measured_disagreement():
    from conftest import compose_cfg

    from garage_exp.loop import cost, stats

    cfg = compose_cfg(config="loop")
    assert "paired by scenario" not in cost.power_line(cfg)  # no pilot has measured a discordant share
    cfg.power.pilot_discordant = 0.1
    n = stats.scenarios_for_paired(float(cfg.power.pilot_rate), 0.1, 0.2, cost.comparisons(cfg))
    line = cost.power_line(cfg)
    assert f"paired by scenario (McNemar, a pilot's discordant share 0.10): {n};" in line
    # the verdict with one seed uses the paired test: whether the sample is enough is said of that test
    assert line.endswith("enough for the paired test" if cfg.heldout_trials * cfg.power.scenario_share >= n
                         else "too few for the paired test")
