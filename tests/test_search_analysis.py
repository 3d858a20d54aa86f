"""The analysis of a study (garage_exp.report.search_analysis, .sensitivity) on synthetic studies built in memory with
the sweeper's trial contract and a known difficulty function: no rendering, seconds each."""

from __future__ import annotations

import numpy as np
import optuna
import pandas as pd
import pytest
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.trial import TrialState, create_trial

from garage_exp.core.errors import GarageError
from garage_exp.report import search_analysis as analysis, sensitivity
from garage_exp.report.trials import distributions, rerun_overrides, trial_table
from garage_exp.report.why_hard import why_hard
from garage_exp.search import objectives

optuna.logging.set_verbosity(optuna.logging.WARNING)

SPACE = {"light.intensity": FloatDistribution(0.1, 1.0),
         "case.actors.target.offset": FloatDistribution(-0.8, 0.8),
         "occluder": CategoricalDistribution(["none", "pillar", "car"])}
HIDE = {"none": 0.0, "pillar": 0.15, "car": 0.1}


def hardness(p: dict) -> float:
    """Dark is hard, the offset's side barely matters, a pillar hides most: the answer the analysis must find."""
    return float(np.clip(0.9 - 0.7 * p["light.intensity"] + 0.02 * p["case.actors.target.offset"]
                         + HIDE[p["occluder"]], 0, 1))


def trial(p: dict, state=TrialState.COMPLETE, multi=False, frame=None, **attrs):
    d = hardness(p) if state == TrialState.COMPLETE else 0.5
    user = {"overrides": [f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in p.items()]
            + ["plan=tiny", "palette.target_colours=[black]"], "run_id": "r", "output_dir": "/tmp/x", "fair_frames": 3, "frames": 4,
            "recall": 1 - d, "confidence": 1 - d,
            "visible_fraction": 0.95 - 0.3 * d - 0.1 * abs(p.get("case.actors.target.offset", 0)), **attrs}
    if frame:
        user["frame"] = str(frame)
    values = None
    if state == TrialState.COMPLETE:
        values = [d, user["visible_fraction"]] if multi else [d]
    return create_trial(params=p, distributions={k: SPACE[k] for k in p}, values=values, state=state,
                        user_attrs=user)


def study_of(n: int, multi=False, seed=0, frames_dir=None) -> optuna.Study:
    """n complete random trials, one pruned (infeasible), one failed, in an in-memory study."""
    names = ["difficulty", "visible_fraction"] if multi else ["difficulty"]
    study = optuna.create_study(directions=["maximize"] * len(names), study_name="synthetic")
    study.set_user_attr("direction_names", names)
    rng = np.random.default_rng(seed)
    for k in range(n):
        p = {"light.intensity": float(rng.uniform(0.1, 1.0)),
             "case.actors.target.offset": float(rng.uniform(-0.8, 0.8)),
             "occluder": str(rng.choice(["none", "pillar", "car"]))}
        frame = None
        if frames_dir is not None:
            from PIL import Image

            frame = frames_dir / f"frame_{k}.png"
            Image.new("RGB", (32, 24), (k * 20 % 255, 80, 120)).save(frame)
        study.add_trial(trial(p, multi=multi, frame=frame))
    hidden = {"light.intensity": 0.2, "case.actors.target.offset": 0.0, "occluder": "pillar"}
    study.add_trial(trial(hidden, TrialState.PRUNED, infeasible=True))
    study.add_trial(trial({"light.intensity": 0.5}, TrialState.FAIL, error="RuntimeError: render crashed"))
    return study


def test_single_objective_report_ranks_only_complete_trials_and_explains(tmp_path):
    frames = tmp_path / "frames_src"
    frames.mkdir()
    study = study_of(30, frames_dir=frames)
    study.enqueue_trial({"light.intensity": 0.3})  # a study still running: a trial not started yet
    out = tmp_path / "analysis"
    written = analysis.analyse(study, out, top=3)
    names = {p.name for p in written}
    assert {"history.png", "slices.png", "importances.png", "importances.csv", "trials.csv", "hardest.csv",
            "search_report.md", "search_report.html", "sensitivity.csv", "sensitivity.png"} <= names
    assert all(p.is_file() for p in written)

    hard = pd.read_csv(out / "hardest.csv")
    done = [t for t in study.trials if t.state == TrialState.COMPLETE]
    expected = sorted(done, key=lambda t: -t.value)[:3]
    assert hard.trial.tolist() == [t.number for t in expected]
    assert hard.difficulty.tolist() == pytest.approx([t.value for t in expected])
    assert set(hard.trial).isdisjoint({30, 31})  # the pruned and failed trials are never ranked

    trials = pd.read_csv(out / "trials.csv")
    assert trials.state.value_counts().to_dict() == {"COMPLETE": 30, "PRUNED": 1, "FAIL": 1, "WAITING": 1}
    assert "render crashed" in trials.set_index("trial").loc[31, "why"]

    imp = pd.read_csv(out / "importances.csv")
    assert imp.parameter.iloc[0] == "light.intensity"  # the factor the difficulty is built on
    assert imp.importance.sum() == pytest.approx(1.0)

    report = (out / "search_report.md").read_text()
    assert "33 trials: 30 complete, 1 pruned as infeasible (no fairly visible frame), 1 failed, 1 waiting" in report
    assert "## Pruned trials" in report and "## Failed trials" in report
    # the hardest scenario is dark: its light sits in the low third, the harder side by the study's own data
    top = expected[0]
    assert top.params["light.intensity"] < 0.4
    section = report.split(f"### 1. trial {top.number}:")[1].split("###")[0]
    line = next(ln for ln in section.splitlines() if ln.startswith("- `light.intensity`"))
    assert "in the low third" in line and ": the harder side (p = " in line
    assert "What makes it hard: hard through `light.intensity` (low third)" in section
    command = "python -m garage_exp " + " ".join(top.user_attrs["overrides"][:-1])
    assert command + " 'palette.target_colours=[black]'" in section  # quoted for the shell
    assert f"](frames/trial_{top.number}.png)" in section and (out / "frames" / f"trial_{top.number}.png").is_file()
    html = (out / "search_report.html").read_text()
    assert html.count("data:image/png;base64,") >= 4 + 3  # figures and the three frames, inside the page


def test_a_bright_trial_is_told_it_is_not_on_the_harder_side(tmp_path):
    study = study_of(30)
    table = trial_table(study)
    bright = next(t for t in study.trials if t.state == TrialState.COMPLETE and t.params["light.intensity"] > 0.75)
    lines = [text for _, _, text in why_hard(bright, table, distributions(study), {})]
    light = next(ln for ln in lines if ln.startswith("`light.intensity`"))
    assert "high third" in light and "not the harder side" in light and "in the low third (" in light


def test_multi_objective_lists_the_pareto_front(tmp_path):
    study = study_of(20, multi=True)
    written = analysis.analyse(study, tmp_path, top=2)
    assert tmp_path / "pareto.png" in written
    report = (tmp_path / "search_report.md").read_text()
    front = {t.number for t in study.best_trials}
    assert 0 < len(front) < 20 and f"{len(front)} trials that no other trial beats on both difficulty and visible_fraction" in report
    trials = pd.read_csv(tmp_path / "trials.csv")
    assert set(trials[trials.on_front].trial) == front
    hard = pd.read_csv(tmp_path / "hardest.csv")
    assert hard.difficulty.is_monotonic_decreasing and len(hard) == 2


def test_too_few_trials_skip_importances_and_sensitivity_with_a_reason(tmp_path):
    study = study_of(1)
    written = analysis.analyse(study, tmp_path)
    report = (tmp_path / "search_report.md").read_text()
    assert "Importances skipped: 1 complete trial(s), fANOVA needs at least 2." in report
    assert "Sensitivity skipped: 1 complete trials, a surrogate needs at least 10" in report
    assert not (tmp_path / "importances.csv").exists()
    assert len(pd.read_csv(tmp_path / "hardest.csv")) == 1
    assert "too few trials on each side" in report
    assert tmp_path / "search_report.html" in written


def test_a_study_with_no_complete_trial_still_reports(tmp_path):
    study = optuna.create_study(direction="maximize", study_name="empty")
    study.add_trial(trial({"light.intensity": 0.5, "occluder": "pillar"}, TrialState.PRUNED, infeasible=True))
    analysis.analyse(study, tmp_path)
    report = (tmp_path / "search_report.md").read_text()
    assert "0 complete, 1 pruned" in report and "No complete trial: nothing to rank." in report
    assert "infeasible: no fairly visible frame" in report


def test_the_command_reports_a_study_in_a_storage_and_refuses_a_wrong_name(tmp_path, capsys):
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    study = optuna.create_study(storage=storage, study_name="stored", direction="maximize")
    for t in study_of(4).trials:
        study.add_trial(t)
    assert analysis.main(["--storage", storage, "-o", str(tmp_path / "out"), "--top", "2"]) == 0
    assert len(pd.read_csv(tmp_path / "out" / "hardest.csv")) == 2
    assert "# Search report: stored" in (tmp_path / "out" / "search_report.md").read_text()
    assert analysis.main(["--storage", storage, "--study", "nope"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"garage_exp.report.search_analysis: {storage}: no study named 'nope' (there are: stored)")
    missing = f"sqlite:///{tmp_path / 'absent.db'}"
    assert analysis.main(["--storage", missing]) == 2 and not (tmp_path / "absent.db").exists()


# --- sensitivity ---------------------------------------------------------------------------------------------------
LINEAR = {"x1": FloatDistribution(0, 1), "x2": FloatDistribution(0, 1), "x3": FloatDistribution(0, 1)}


def linear(p: dict) -> float:
    """y = 4 x1 + x2 + 0 x3 on the unit cube: S1 = ST = 16/17, 1/17, 0."""
    return 4 * p["x1"] + p["x2"]


def test_saltelli_design_gives_the_known_indices_and_steps_ints():
    space = {**LINEAR, "n": IntDistribution(1, 5), "occluder": CategoricalDistribution(["a", "b"])}
    design = sensitivity.saltelli_design(space, 256, seed=1)
    assert len(design) == 256 * (4 + 2) and set(design[0]) == {"x1", "x2", "x3", "n"}
    assert all(isinstance(p["n"], int) and 1 <= p["n"] <= 5 for p in design)
    assert design == sensitivity.saltelli_design(space, 256, seed=1)

    study = optuna.create_study(direction="maximize")
    dists = {k: space[k] for k in design[0]}
    for k, p in enumerate(design):  # the categorical held fixed by the sweeper; n inert like x3
        study.add_trial(create_trial(params=p, distributions=dists, values=[linear(p)], user_attrs={"saltelli": k}))
    table = sensitivity.sobol_indices(study, seed=0).set_index("factor")
    assert (table.method == "saltelli").all() and (table.trials == len(design)).all()
    assert table.S1["x1"] == pytest.approx(16 / 17, abs=0.05) and table.S1["x2"] == pytest.approx(1 / 17, abs=0.03)
    assert abs(table.ST["x3"]) < 0.01 and abs(table.ST["n"]) < 0.01
    assert table.ST["x1"] > table.ST["x2"] > max(table.ST["x3"], table.ST["n"])
    assert (table.S1_conf[["x1", "x2"]] > 0).all() and table.S1["x1"] - table.S1_conf["x1"] > 0.5


def test_an_incomplete_design_falls_back_to_the_surrogate():
    design = sensitivity.saltelli_design(LINEAR, 8, seed=0)
    study = optuna.create_study(direction="maximize")
    for k, p in enumerate(design):
        failed = k == 3
        study.add_trial(create_trial(params=p, distributions=LINEAR, values=None if failed else [linear(p)],
                                     state=TrialState.FAIL if failed else TrialState.COMPLETE,
                                     user_attrs={"saltelli": k}))
    assert sensitivity.saltelli_outputs(study) is None
    assert (sensitivity.sobol_indices(study).method == "surrogate").all()


def test_surrogate_orders_the_factors_of_a_random_study_and_finds_the_inert_one():
    study = optuna.create_study(direction="maximize")
    rng = np.random.default_rng(3)
    for _ in range(60):
        p = {k: float(rng.random()) for k in LINEAR}
        study.add_trial(create_trial(params=p, distributions=LINEAR, values=[linear(p) + rng.normal(0, 0.02)]))
    study.add_trial(create_trial(params={"x1": 0.5}, distributions={"x1": LINEAR["x1"]}, state=TrialState.PRUNED))
    table = sensitivity.sobol_indices(study, seed=0)
    assert table.factor.tolist() == ["x1", "x2", "x3"] and (table.method == "surrogate").all()
    t = table.set_index("factor")
    assert t.ST["x1"] == pytest.approx(16 / 17, abs=0.05) and t.ST["x2"] == pytest.approx(1 / 17, abs=0.03)
    assert abs(t.ST["x3"]) < 0.02 and t.ST["x3"] - t.ST_conf["x3"] < 0.01  # inert: zero inside its interval
    assert t.ST["x2"] - t.ST_conf["x2"] > t.ST["x3"] + t.ST_conf["x3"]  # x2's small effect is told apart
    assert "crowd" not in sensitivity.method_text(table)  # random trials cover the ranges


def test_trials_crowded_in_a_corner_are_said_to_be():
    study = optuna.create_study(direction="maximize")
    rng = np.random.default_rng(4)
    for _ in range(20):  # an optimiser's habit: most trials where it is hardest (x1 high)
        p = {"x1": float(rng.uniform(0.7, 1.0)), "x2": float(rng.random()), "x3": float(rng.random())}
        study.add_trial(create_trial(params=p, distributions=LINEAR, values=[linear(p)]))
    text = sensitivity.method_text(sensitivity.sobol_indices(study, seed=0))
    assert "The trials crowd part of the ranges" in text and "search.sampler=saltelli" in text


@pytest.mark.parametrize("n", [0, 100])
def test_a_design_size_that_is_not_a_power_of_two_is_one_line(n):
    with pytest.raises(GarageError, match=f"power of 2.*not {n}"):
        sensitivity.saltelli_design(LINEAR, n, seed=0)


def test_no_continuous_factor_is_one_line():
    with pytest.raises(GarageError, match="no continuous factor"):
        sensitivity.saltelli_design({"occluder": CategoricalDistribution(["a"])}, 8, seed=0)


def test_the_trial_table_names_its_column_by_the_objective_and_the_rerun_keeps_the_fairness_rule(tmp_path):
    """A late study's trials.csv and hardest.csv hold `lateness`, not `difficulty` (issue 31, item 5); the rerun
    command keeps what the job itself reads of `search.*` (which frames are fair tests), not the rest."""
    study = optuna.create_study(directions=["maximize"], study_name="late")
    study.set_user_attr("direction_names", ["lateness"])
    study.set_user_attr("untestable", "never fairly visible before the critical distance")
    study.set_user_attr("attr_headings", objectives.shown())  # as search.study.open_study stores them
    study.add_trial(create_trial(params={"light.intensity": 0.2}, distributions={"light.intensity": SPACE["light.intensity"]},
                                 state=TrialState.PRUNED, user_attrs={"overrides": ["case=stepout"], "infeasible": True}))
    for k, value in enumerate([0.2, 0.7, 0.4]):
        study.add_trial(create_trial(
            params={"light.intensity": 0.3 + 0.2 * k}, distributions={"light.intensity": SPACE["light.intensity"]},
            values=[value], user_attrs={"overrides": ["case=stepout", "search.min_visible=0.3", "search.trials=3",
                                                      f"light.intensity={0.3 + 0.2 * k}", f"search.trial={k}"],
                                        "fair_frames": 2, "frames": 4, "visible_fraction": 0.8, "late": 0.0,
                                        "detection_distance": 7.0}))
    analysis.analyse(study, tmp_path, top=2)
    trials, hard = pd.read_csv(tmp_path / "trials.csv"), pd.read_csv(tmp_path / "hardest.csv")
    assert "lateness" in trials and "difficulty" not in trials and trials.lateness.tolist()[1:] == [0.2, 0.7, 0.4]
    assert trials.why[0] == "infeasible: never fairly visible before the critical distance"
    assert hard.lateness.tolist() == [0.7, 0.4] and "difficulty" not in hard
    # the late objective's own attributes, as it declares them: those the trials hold, not the empty TTC
    assert hard.detection_distance.tolist() == [7.0, 7.0] and "ttc_at_detection" not in hard
    assert trials.ttc_at_detection.isna().all()
    assert rerun_overrides(study.trials[2]) == ["case=stepout", "search.min_visible=0.3",
                                                         "light.intensity=0.5"]
    report = (tmp_path / "search_report.md").read_text()
    assert "### 1. trial 2: lateness 0.70" in report
    assert "| late | detection distance (m) |" in report
    assert "1 pruned as infeasible (never fairly visible before the critical distance)" in report
    assert "python -m garage_exp case=stepout search.min_visible=0.3 light.intensity=0.5\n" in report


def test_sides_without_spread_get_no_test_and_no_p_value():
    """Every trial on each side scoring the same makes Welch's t infinite (p = 0, "the harder side") or undefined
    (p = nan): no test is made and no p-value printed (issue 42, item 8)."""
    study = study_of(30)
    table = trial_table(study)
    low = table["light.intensity"] < 0.1 + 0.9 / 3
    table["difficulty"] = np.where(low, 0.9, 0.1)
    dark = next(t for t in study.trials if t.state == TrialState.COMPLETE and t.params["light.intensity"] < 0.3)
    light = next(text for param, _, text in why_hard(dark, table, distributions(study), {})
                 if param == "light.intensity")
    assert ": no test (every trial on either side scores the same: difficulty 0.90 there" in light, light
    assert "p = " not in light


def test_a_rate_without_episodes_gets_no_fisher_p_value():
    from garage_exp.gym.app import rates_line

    assert rates_line((0, 0), (2, 4)).endswith("; no test (no episodes on one side)")
    assert "Fisher's exact p = 1.00" in rates_line((2, 4), (2, 4))


def test_a_large_studys_importances_come_from_a_seeded_sample_and_say_so(monkeypatch):
    """fANOVA's cost grows with trials x parameters (700 trials of the wide space's 34: over 10 minutes): above
    FANOVA_TRIALS complete trials the importances come from a seeded sample of that many, the same every time, and
    still find what makes the scenarios hard; below it, from every trial as before (no note)."""
    from garage_exp.report import why_hard

    monkeypatch.setattr(why_hard, "FANOVA_TRIALS", 60)
    study = study_of(90)
    first, note = why_hard.importances(study)
    again, _ = why_hard.importances(study)
    assert note == "Importances from a seeded sample of 60 of the 90 complete trials." and first == again
    assert max(first, key=first.get) == "light.intensity"
    small, none = why_hard.importances(study_of(50))
    assert none == "" and max(small, key=small.get) == "light.intensity"


def test_a_choice_of_many_values_goes_to_fanova_as_its_index_and_keeps_its_name():
    """Optuna's fANOVA averages a one-hot choice's marginal over 2^k points for k split columns: an archive whose
    offspring keep their parents' values (the directed emitter) made a study of the wide space's 43 target kinds run
    for over 20 minutes. A choice of more than FANOVA_ONEHOT_MOST values is handed over as its index (an integer of
    the same name); a smaller choice stays one-hot, and the kind that makes scenarios hard is still found."""
    from garage_exp.report import why_hard

    kinds = [f"car{k}" for k in range(43)]
    dists = {"kind": CategoricalDistribution(kinds), "light": CategoricalDistribution(["bright", "dim"]),
             "gap": FloatDistribution(0.0, 1.0)}
    rng = np.random.default_rng(0)
    study = optuna.create_study(direction="maximize")
    for k in range(120):  # few kinds, each repeated (as a directed archive's offspring repeat theirs)
        kind = kinds[int(rng.integers(0, 43)) if k < 20 else int(rng.integers(0, 20)) // 2 * 2]
        params = {"kind": kind, "light": "dim" if k % 3 else "bright", "gap": float(rng.uniform())}
        hard = 0.9 if kinds.index(kind) % 4 == 0 else 0.1
        study.add_trial(create_trial(values=[hard + 0.05 * params["gap"]], params=params, distributions=dists))
    handed = why_hard.indexed_choices(study).trials[0]
    assert handed.distributions["kind"] == IntDistribution(0, 42) and handed.params["kind"] == kinds.index(
        study.trials[0].params["kind"])
    assert handed.distributions["light"] == dists["light"] and handed.params["gap"] == study.trials[0].params["gap"]
    found, note = why_hard.importances(study)
    assert note == "" and set(found) == {"kind", "light", "gap"} and max(found, key=found.get) == "kind"
    small = optuna.create_study(direction="maximize")
    small.add_trials([create_trial(values=t.values, params={"light": t.params["light"]},
                                   distributions={"light": dists["light"]}) for t in study.trials])
    assert why_hard.indexed_choices(small) is small  # nothing to index: the study itself, as before
