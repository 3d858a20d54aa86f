"""Graded levels, measured (garage_exp/search/grade.py): a suite's levels, fresh draws near each level's trials,
the fresh draws' own study run by the suite's command, and the failure rate per level with Spearman's rho."""

import math
import sys

import numpy as np
import optuna
import optuna.distributions as od
import pytest
from conftest import compose_cfg, run_module
from optuna.trial import TrialState, create_trial

from garage_exp.core.errors import GarageError
from garage_exp.search import grade as grade_mod
from garage_exp.search import study as study_mod
from garage_exp.search.suite import band_of, bands_of

DISTS = {"light.intensity": od.FloatDistribution(0.1, 1.0), "case.actors.target.distance": od.FloatDistribution(3.0, 10.0),
         "occluder": od.CategoricalDistribution(["pillar", "none"]), "palette.parked_occupancy": od.FloatDistribution(
             0.01, 1.0, log=True), "case.site_index": od.IntDistribution(0, 9)}


def suite_study(storage=None, name="suite", argv=("plan=tiny", "light.intensity=interval(0.1,1.0)")):
    """A suite's study: 40 complete trials whose difficulty grows with the distance (so each level has trials)."""
    study = optuna.create_study(study_name=name, storage=storage, direction="maximize")
    rng = np.random.default_rng(1)
    for k in range(40):
        params = {"light.intensity": float(rng.uniform(0.1, 1.0)), "case.actors.target.distance": 3.0 + 7.0 * k / 39,
                  "occluder": ["pillar", "none"][k % 2], "palette.parked_occupancy": float(rng.uniform(0.01, 1.0)),
                  "case.site_index": int(k % 10)}
        study.add_trial(create_trial(values=[min(k / 39, 0.999)], params=params, distributions=DISTS,
                                     user_attrs={"overrides": [f"{n}={v}" for n, v in params.items()]}))
    study.set_user_attr("argv", list(argv))
    return study


def test_levels_are_equal_bands_of_the_confidence_from_easiest_to_hardest():
    bands = grade_mod.level_bands(5)
    assert list(bands) == [f"level_{k}" for k in range(1, 6)]
    assert band_of(1.0, bands) == "level_1" and band_of(0.81, bands) == "level_1"
    assert band_of(0.79, bands) == "level_2" and band_of(0.0, bands) == "level_5" and band_of(0.19, bands) == "level_5"
    edges = sorted(x for low_high in bands.values() for x in low_high)
    assert edges[0] == 0.0 and edges[-1] == 1.01
    cfg = compose_cfg("search.mode=suite", "search.suite.levels=5")
    assert bands_of(cfg.search) == bands
    assert bands_of(compose_cfg().search) == {"easy": [0.7, 1.01], "moderate": [0.4, 0.7], "hard": [0.0, 0.4]}


@pytest.mark.parametrize("levels, bands, message", [
    (1, None, "at least 2"), (-3, None, "at least 2"), (5, "{a: [0.0, 0.5]}", "either bands or levels")])
def test_a_bad_level_count_is_one_line_naming_it(levels, bands, message):
    extra = [f"+search.suite.bands={bands}"] if bands else []
    cfg = compose_cfg(f"search.suite.levels={levels}", *extra)
    with pytest.raises(GarageError, match=message) as err:
        study_mod.check_search(cfg.search)
    assert err.value.where == "search.suite.levels"


def test_a_nudge_stays_in_its_range_keeps_choices_and_moves_by_about_sigma():
    rng = np.random.default_rng(0)
    dist = od.FloatDistribution(0.0, 10.0)
    moved = np.array([grade_mod.nudged(9.9, dist, 0.05, rng) for _ in range(2000)])
    assert moved.min() >= 0.0 and moved.max() <= 10.0
    assert 0.3 < np.abs(moved - 9.9).mean() < 0.5  # the half-normal's mean 0.4 (sigma 0.5), reflected at 10
    assert (moved < 9.9).mean() > 0.75  # reflected off the top end, most land below
    assert grade_mod.nudged("none", od.CategoricalDistribution(["pillar", "none"]), 0.5, rng) == "none"
    ints = {grade_mod.nudged(5, od.IntDistribution(0, 9), 0.2, rng) for _ in range(200)}
    assert ints <= set(range(10)) and len(ints) > 3 and all(isinstance(v, int) for v in ints)
    logs = [grade_mod.nudged(0.02, od.FloatDistribution(0.01, 1.0, log=True), 0.05, rng) for _ in range(200)]
    assert min(logs) >= 0.01 and max(logs) < 0.05  # 5 % of the log range moves 0.02 by a factor of ~1.26


def test_fresh_draws_are_near_their_level_never_its_own_trials_and_seeded():
    study = suite_study()
    draws = grade_mod.fresh_draws(study, levels=5, per_level=6, sigma=0.05, seed=3)
    assert sorted({level for level, _ in draws}) == [1, 2, 3, 4, 5] and len(draws) == 30
    members = grade_mod.level_members(study, 5)
    own = [t.params for trials in members.values() for t in trials]
    for level, params in draws:
        assert "seed" in params and params not in own
        searched = {k: v for k, v in params.items() if k != "seed"}
        nearest = min(abs(searched["case.actors.target.distance"] - t.params["case.actors.target.distance"])
                      for t in members[level])
        assert nearest < 7.0 * 0.05 * 5  # within 5 sigma of one of its level's trials
        assert searched["occluder"] in ("pillar", "none")
    assert draws == grade_mod.fresh_draws(study, 5, 6, 0.05, seed=3)
    assert draws != grade_mod.fresh_draws(study, 5, 6, 0.05, seed=4)


def test_a_fresh_draw_keeps_its_parents_searched_seeds():
    """A seed names one garage (one set of parked cars, one set of failed lamps): 5 % of its range away is another
    garage, not a near one, so a fresh draw keeps it and moves only the quantities."""
    dists = {"plan.seed": od.IntDistribution(0, 999999), "light.seed": od.IntDistribution(0, 999),
             "light.intensity": od.FloatDistribution(0.1, 1.0)}
    study = optuna.create_study(direction="maximize")
    for k in range(10):
        study.add_trial(create_trial(values=[k / 10], params={"plan.seed": 1000 * k + 7, "light.seed": k,
                                                              "light.intensity": 0.5}, distributions=dists))
    draws = grade_mod.fresh_draws(study, levels=5, per_level=8, sigma=0.05, seed=0)
    parents = {(t.params["plan.seed"], t.params["light.seed"]) for t in study.trials}
    assert all((p["plan.seed"], p["light.seed"]) in parents for _, p in draws)
    assert any(p["light.intensity"] != 0.5 for _, p in draws)  # the quantities still move


def grade_study(rates: dict[int, tuple[int, int, int]]):
    """A grade study: per level (failed, passed, not fair) finished trials."""
    study = optuna.create_study(direction="maximize")
    dist = {"x": od.FloatDistribution(0, 1)}
    for level, (failed, passed, unfair) in rates.items():
        for k in range(failed + passed):
            study.add_trial(create_trial(values=[0.8 if k < failed else 0.2], params={"x": 0.5}, distributions=dist,
                                         user_attrs={"grade_level": level}))
        for _ in range(unfair):
            study.add_trial(create_trial(state=TrialState.PRUNED, params={"x": 0.5}, distributions=dist,
                                         user_attrs={"grade_level": level}))
    study.add_trial(create_trial(values=[0.9], params={"x": 0.5}, distributions=dist))  # not a fresh draw
    return study


def test_the_failure_rate_per_level_counts_only_fair_fresh_draws_and_rho_ranks_them():
    table, rho = grade_mod.measure(grade_study({1: (0, 10, 2), 2: (2, 8, 0), 3: (5, 5, 1), 4: (9, 1, 0)}), 0.6)
    assert list(table.level) == [1, 2, 3, 4] and list(table.drawn) == [12, 10, 11, 10]
    assert list(table.scored) == [10, 10, 10, 10] and list(table.failed) == [0, 2, 5, 9]
    assert table.failure_rate.tolist() == [0.0, 0.2, 0.5, 0.9]
    assert table.low[0] == 0.0 and 0.0 < table.high[0] < 0.35  # Wilson: never empty at 0
    assert rho == pytest.approx(1.0)
    _, shuffled = grade_mod.measure(grade_study({1: (9, 1, 0), 2: (0, 10, 0), 3: (5, 5, 0)}), 0.6)
    assert shuffled == pytest.approx(-0.5)
    _, two = grade_mod.measure(grade_study({1: (0, 3, 0), 2: (3, 0, 0)}), 0.6)
    assert math.isnan(two)


def test_grade_runs_the_suites_own_command_over_the_enqueued_draws(tmp_path):
    """The fresh draws' study holds exactly the draws (the stand-in command runs what is enqueued, as the search
    asks for enqueued trials first), run with the suite's own overrides, `seed` searched, its own study name."""
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    suite_study(storage, argv=["plan=tiny", "seed=7", "search.trials=99", "light.intensity=interval(0.1,1.0)",
                               "search.mode=suite", "search.suite.levels=5"])
    seen = {}

    def run(cmd):
        seen["cmd"] = cmd
        name = next(a.split("=", 1)[1] for a in cmd if a.startswith("search.study="))
        study = optuna.load_study(study_name=name, storage=storage)
        while True:
            trial = study.ask()  # the enqueued ones first
            if "grade_level" not in trial.user_attrs:
                study.tell(trial, state=TrialState.FAIL)
                break
            # an enqueued trial's values come back when its keys are asked (the search asks the whole space)
            hard = trial.suggest_float("case.actors.target.distance", 3.0, 10.0) / 10.0  # farther: harder
            study.tell(trial, [hard])
        return 0

    table, rho = grade_mod.grade(storage, "suite", tmp_path / "out", levels=5, fresh=8, sigma=0.02, run=run)
    cmd = seen["cmd"]
    assert cmd[:5] == [sys.executable, "-m", "garage_exp", "-m", "hydra/sweeper=search"]
    assert "plan=tiny" in cmd and "light.intensity=interval(0.1,1.0)" in cmd
    assert "seed=7" not in cmd and "search.trials=99" not in cmd and "search.mode=suite" not in cmd
    assert "seed=int(interval(0,999999))" in cmd and "search.trials=40" in cmd and "search.study=suite-grade-0" in cmd
    rates = table.failure_rate.tolist()
    assert int(table.drawn.sum()) == 40 and rates == sorted(rates) and rates[0] == 0.0 and rates[-1] == 1.0
    assert rho > 0.8
    assert (tmp_path / "out" / "grade.csv").is_file() and (tmp_path / "out" / "grade.png").is_file()


def test_grade_of_a_missing_study_is_one_line(tmp_path):
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    suite_study(storage)
    r = run_module("garage_exp.search.grade", ["--storage", storage, "--study", "nope", "-o", str(tmp_path / "o")],
                   tmp_path)
    assert r.returncode == 2 and "no study 'nope'" in r.stderr and not (tmp_path / "o").exists()


def test_the_fresh_draws_run_through_the_real_search_as_enqueued(tmp_path):
    """The grade's own child command: the suite's overrides (here a dry run: nothing rendered, every trial pruned as
    untestable) over the enqueued draws, `seed` searched; the study holds exactly the draws, with their levels."""
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    study = optuna.create_study(study_name="suite", storage=storage, direction="maximize")
    dist = {"light.intensity": od.FloatDistribution(0.1, 1.0)}
    for k, value in enumerate((0.1, 0.9)):  # level 1 and level 2 of two
        study.add_trial(create_trial(values=[value], params={"light.intensity": 0.2 + 0.6 * k}, distributions=dist))
    study.set_user_attr("argv", ["plan=tiny", "dry_run=true", "light.intensity=interval(0.1,1.0)",
                                 f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"])
    r = run_module("garage_exp.search.grade", ["--storage", storage, "--study", "suite", "--levels", "2", "--fresh", "2",
                                               "-o", str(tmp_path / "out")], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    graded = optuna.load_study(study_name="suite-grade-0", storage=storage)
    trials = graded.get_trials()
    assert sorted(t.user_attrs["grade_level"] for t in trials) == [1, 1, 2, 2]
    assert all(t.state == TrialState.PRUNED and 0 <= t.params["seed"] < 1_000_000 for t in trials)
    assert "level 1: 0 of 0 fresh draws failed" in r.stdout and "2 not fair" in r.stdout
