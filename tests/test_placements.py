"""Where actors may stand (issue 31, items 1, 2 and 9): one rule (scenario/place.py `clash`: no two footprints in
one another) decides it for a job's frames, the adversary's action space and a search's trials alike.

- Every episode the environment can play reruns as a job: many random episodes, each exported as a scenario and
  built as a job's scene description (no rendering), place every actor where the environment placed it, frame for
  frame, and pass the job's checks; the environment's open bounds stop where a job's refusals begin.
- A dry run refuses what the real run refuses at scene build, in the same words; an exported scenario's refusal
  names its own file.
- A search prunes a trial whose sampled values put actors in one another, counts it as infeasible, and refuses a
  space only when no probed point is feasible, naming the override at fault.

On the research plan with case=stepout (the tiny plan has no straight lane with bays)."""

from __future__ import annotations

import numpy as np
import optuna
import pytest
from conftest import compose_cfg, require, run_app
from omegaconf import OmegaConf
from optuna.trial import TrialState

from garage_exp.core.errors import GarageError, Infeasible
from garage_exp.run.spec import scene_spec

OVERLAP = ["case=stepout", "case.actors.child.offset=0.25", "case.motion.end=19", "case.motion.along.child.at=19.5"]
EPISODES = 40


def make_env(tmp_path_factory, *overrides):
    """The step-out environment (no episode is rendered here: its moves and poses only)."""
    require("vehicles", "models")
    from garage_exp.gym.env import StepOutEnv, compose

    uri = f"sqlite:///{tmp_path_factory.mktemp('env') / 'mlflow.db'}"
    return StepOutEnv(compose(["case.motion.start=14", "case.motion.step=1.0", f"tracking.uri={uri}", *overrides]))


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    return make_env(tmp_path_factory)  # the default movers: the child's out each step, its offset once


def play(env, actions: list) -> dict:
    """An episode's record as the environment writes it (reward.episode's `ego` and `values`), played without
    rendering, with each frame's poses beside it."""
    env._state_reset()
    frames = []
    for action in actions:
        env.move(action)
        ego, others = env._poses(env.drive[env.k])
        frames.append({"ego": env.drive[env.k], **{m.name: round(env.values[m.name], 6) for m in env.movers},
                       "poses": {"ego": ego, **{n: p for n, p in others.items() if p is not None}}})
    names = [m.name for m in env.movers]
    return {"ego": [f["ego"] for f in frames], "values": {n: [f[n] for f in frames] for n in names},
            "variant": 0, "poses": [f["poses"] for f in frames]}


def rerun(env, record: dict):
    """The episode's exported scenario built as a job's scene would be (scenario.make_case): its shots."""
    from garage_exp.gym.export import scenario_values
    from garage_exp.run.preflight import _library, classified_plan, resolve_plan_path
    from garage_exp.scenario import make_case

    cfg = OmegaConf.merge(env.job, scenario_values(env.job, record, env.movers))
    classified = classified_plan(resolve_plan_path(cfg.plan))
    return make_case(scene_spec(cfg), classified, _library(), np.random.default_rng(int(cfg.seed))).shots


def test_the_adversarys_offset_stops_where_a_job_refuses(env):
    """The child's offset (bounds left open) runs to the parked cars' sides: a job takes the environment's
    bounds and refuses 2 mm past either, naming how far the child fits."""
    offset = next(m for m in env.movers if m.name == "child.offset")
    out = next(m for m in env.movers if m.name == "child.out")
    assert (out.low, out.high) == (-1.0, 2.5)  # given bounds that fit stay as they were
    assert -0.13 < offset.low < -0.1 and 0.1 < offset.high < 0.12, offset  # (the gap: 0.54 m, the child: 0.35 m)
    for bound, past in ((offset.low, offset.low - 0.002), (offset.high, offset.high + 0.002)):
        record = {"ego": list(env.drive[1:]), "values": {"child.out": [-1.0] * (len(env.drive) - 1),
                                                          "child.offset": [bound] * (len(env.drive) - 1)}}
        assert rerun(env, record)
        record["values"]["child.offset"] = [past] * (len(env.drive) - 1)
        with pytest.raises(Infeasible, match=r"stepout.yaml: case.actors: actors child and car_(left|right) overlap"
                                             r".*case.actors.child.offset fits"):
            rerun(env, record)


@pytest.mark.parametrize("movers", ["default", "offset only"])
def test_every_random_episode_reruns_as_a_job(env, tmp_path_factory, movers):
    """Many episodes of random actions (and the extremes: full speed out, back, the offset at either bound),
    each of random length, exported and built as a job: every frame places every actor as the environment did.
    With the offset its only mover, the environment holds the child at its own `out` while the case's co-motion
    would walk it out: the export holds it there too."""
    if movers != "default":
        env = make_env(tmp_path_factory, "gym.movers=[{actor: child, key: offset, low: null, high: null, once: true}]")
    rng = np.random.default_rng(31)
    n = len(env.movers)
    episodes = [[np.full(n, a)] * (len(env.drive) - 1) for a in (-1.0, 1.0)]
    if n == 2:
        episodes += [[np.array([1.0, -1.0])] * (len(env.drive) - 1), [np.array([-1.0, 1.0])] * (len(env.drive) - 1)]
    for _ in range(EPISODES):
        length = int(rng.integers(1, len(env.drive)))
        episodes.append(list(rng.uniform(-1.0, 1.0, size=(length, n))))
    seen_offsets = []
    for actions in episodes:
        record = play(env, actions)
        shots = rerun(env, record)
        assert len(shots) == len(record["ego"])
        seen_offsets.append(record["values"]["child.offset"][0])
        for shot, poses in zip(shots, record["poses"]):
            job = {"ego": shot.ego, **{n: p for n, p in shot.poses.items() if p is not None}}
            assert job.keys() == poses.keys()
            for name, pose in poses.items():
                assert (job[name].x, job[name].y, job[name].yaw) == pytest.approx((pose.x, pose.y, pose.yaw),
                                                                                  abs=1e-5), name
    offset = next(m for m in env.movers if m.name == "child.offset")
    assert min(seen_offsets) == offset.low and max(seen_offsets) == offset.high  # the extremes were played


def test_a_given_bound_past_the_cars_is_refused_naming_it(tmp_path):
    """A bound given past where the child fits is refused when the environment is made, one line naming it and
    how far the child fits."""
    require("vehicles", "models")
    from garage_exp.gym.env import StepOutEnv, compose

    movers = "gym.movers=[{actor: child, key: out, low: -1.0, high: 2.5}, {actor: child, key: offset, low: -0.25, " \
             "high: 0.05, once: true}]"
    with pytest.raises(GarageError) as refused:
        StepOutEnv(compose(["case.motion.start=14", "case.motion.step=1.0", movers,
                            f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"]))
    message = str(refused.value)
    assert "\n" not in message and message.startswith("gym.movers.1.low: child.offset at -0.25 puts "), message
    assert "child and car_left in one another" in message and "it fits to -0.12" in message, message


def test_a_dry_run_refuses_what_the_real_run_refuses_in_the_same_words(tmp_path):
    require("vehicles", "models")
    for sub in ("real", "dry"):
        (tmp_path / sub).mkdir()
    real = run_app([*OVERLAP, f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"], tmp_path / "real",
                   fresh_store=True)
    dry = run_app([*OVERLAP, "dry_run=true", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"], tmp_path / "dry",
                  fresh_store=True)
    lines = [[line for line in r.stderr.splitlines() if line.startswith("garage_exp:")] for r in (real, dry)]
    assert (real.returncode, dry.returncode) == (2, 2), (real.stderr[-2000:], dry.stderr[-2000:])
    assert len(lines[0]) == 1 and lines[0] == lines[1], lines
    assert "actors child and car_right overlap" in lines[0][0] and not (tmp_path / "mlflow.db").exists()


def test_an_exported_scenario_names_its_own_file(env, tmp_path):
    """A scenario file from a suite whose child stands in a parked car (written by hand past the bounds): the
    refusal names that file, not conf/case/stepout.yaml; the same suite's legal episode runs (dry run)."""
    from garage_exp.gym.export import scenario_yaml

    suite = tmp_path / "suite"
    (suite / "scenario").mkdir(parents=True)
    good = play(env, [np.array([1.0, 1.0])] * 3)
    bad = {**good, "values": {**good["values"], "child.offset": [0.25] * 3}}
    for name, record in (("good_1", good), ("bad_1", bad)):
        record.update({"late": False, "critical_distance": 5.0, "detection_distance": 9.0, "difficulty": 0.2,
                       "fair_frames": 3})
        (suite / "scenario" / f"{name}.yaml").write_text(scenario_yaml(env.job, name, record, env.movers))
    uri = f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"
    for sub in ("bad", "good"):
        (tmp_path / sub).mkdir()
    r = run_app(["--config-dir", str(suite), "+scenario=bad_1", "dry_run=true", uri], tmp_path / "bad")
    assert r.returncode == 2, r.stderr[-2000:]
    assert f"garage_exp: {suite / 'scenario' / 'bad_1.yaml'}: case.actors: actors child and car_right overlap" \
        in r.stderr, r.stderr[-2000:]
    r = run_app(["--config-dir", str(suite), "+scenario=good_1", "dry_run=true", uri], tmp_path / "good")
    assert r.returncode == 0, r.stderr[-2000:]


# -- the search ---------------------------------------------------------------------------------------------------

SEARCH = ["-m", "hydra/sweeper=search", "case=stepout", "dry_run=true"]


def stores(tmp_path) -> list[str]:
    return [f"search.storage=sqlite:///{tmp_path / 'optuna.db'}", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"]


def test_a_space_no_point_of_which_is_feasible_names_the_override_at_fault(tmp_path):
    """The light is not blamed for the child's offset: the refusal names the offset's override."""
    require("vehicles")
    r = run_app([*SEARCH, "search.trials=4", "light.intensity=interval(0.1,1.0)",
                 "case.actors.child.offset=interval(0.2,0.3)", *stores(tmp_path)], tmp_path, fresh_store=True)
    lines = [line for line in r.stderr.splitlines() if line.startswith("garage_exp:")]
    assert r.returncode == 2 and len(lines) == 1, r.stderr[-2000:]
    assert lines[0].startswith("garage_exp: search space case.actors.child.offset=interval(0.2,0.3): no probed "
                               "point of the space is feasible"), lines
    assert "light.intensity" not in lines[0] and not (tmp_path / "optuna.db").exists()


def test_trials_whose_actors_overlap_are_pruned_and_counted_infeasible(tmp_path):
    """A space with infeasible points runs: each trial whose offset puts the child in a car is pruned as
    infeasible (saying why), the others run (plan-only trials: pruned for want of a fair frame)."""
    require("vehicles")
    r = run_app([*SEARCH, "search.trials=4", "search.sampler=grid", "case.actors.child.offset=choice(0.0,0.05,0.2,0.3)",
                 *stores(tmp_path)], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    url = f"sqlite:///{tmp_path / 'optuna.db'}"
    study = optuna.load_study(study_name=optuna.get_all_study_names(url)[0], storage=url)
    trials = study.get_trials()
    assert len(trials) == 4 and all(t.state == TrialState.PRUNED and t.user_attrs["infeasible"] for t in trials)
    overlapping = sorted(t.params["case.actors.child.offset"] for t in trials if "placement" in t.user_attrs)
    assert overlapping == [0.2, 0.3], [(t.params, t.user_attrs) for t in trials]  # it fits up to about 0.108 m
    assert all("actors child and car_right overlap" in t.user_attrs["placement"] for t in trials
               if "placement" in t.user_attrs)
    assert r.stdout.count("actors child and car_right overlap") == 2 and "4 trials (4 infeasible)" in r.stdout


def test_an_infeasible_jobs_return_prunes_its_trial():
    from garage_exp.search.loop import line, outcome

    out = outcome({"error": "/x/stepout.yaml: case.actors: actors child and car_right overlap (variant 'v', "
                            "position 14)", "infeasible": True}, "late")
    assert out.state == TrialState.PRUNED and out.values is None and out.attrs["infeasible"]
    assert line(2, out, 6, "late") == ("garage_exp: trial 2 (3 of 6): actors child and car_right overlap (variant 'v', position 14): "
                               "infeasible")
    assert outcome({"error": "RuntimeError: boom"}, "late").state == TrialState.FAIL  # other errors still fail


def test_the_prescreen_leaves_an_overlapping_trial_to_its_job(tmp_path, monkeypatch, caplog):
    """The pre-screen's own preflight meets the overlap first: it hands the trial to its job (which refuses it
    before rendering, and the trial is pruned), without a "pre-screen failed" warning."""
    from types import SimpleNamespace

    from garage_exp.search import prescreen
    from garage_exp.search import space as space_mod
    from garage_exp.search import study as study_mod
    from garage_exp.search.loop import SearchLoop

    cfg = compose_cfg("plan=tiny", f"search.storage=sqlite:///{tmp_path / 'optuna.db'}", "search.prescreen.level=truth")
    space = space_mod.build(["light.intensity=interval(0.1,1.0)"], cfg, {})

    def look(_cfg):
        raise Infeasible("actors child and car_right overlap", "case.actors", ("child", "car_right"))

    monkeypatch.setattr(prescreen, "look", look)
    launched = []

    def launch(batch, idx):
        launched.append(idx)
        return [SimpleNamespace(return_value={"error": "f.yaml: case.actors: actors child and car_right overlap",
                                              "infeasible": True})]

    study = study_mod.open_study(cfg.search, "s", 0, space.params)
    SearchLoop(cfg.search, space, study, launch, 2, compose=lambda overrides: cfg).run()
    assert launched == [0, 1] and "pre-screen failed" not in caplog.text
    assert all(t.state == TrialState.PRUNED and t.user_attrs["placement"] for t in study.trials)


def test_the_overrides_at_fault_are_those_that_place_the_actors():
    from garage_exp.search.space import at_fault

    lines = ["light.intensity=interval(0.1,1.0)", "case.actors.child.offset=interval(0.2,0.3)",
             "case.actors.car_before1.gap=interval(0,1)", "case=stepout"]
    assert at_fault(lines, ("child", "car_right")) == ["case.actors.child.offset=interval(0.2,0.3)"]
    assert at_fault(["light.intensity=0.5", "case.motion.end=4", "case=stepout"], ("child", "car_right")) == \
        ["case.motion.end=4"]
    assert at_fault(["light.intensity=0.5", "case=stepout"], ("child",)) == ["case=stepout"]
    assert at_fault(["light.intensity=0.5"], ("child",)) == []


def test_a_jobs_overlap_is_an_infeasible_error_naming_the_two_actors():
    """The job's refusal is core.errors.Infeasible (what the search prunes), through the case file's wrapping."""
    require("vehicles")
    from garage_exp.run.preflight import preflight

    with pytest.raises(Infeasible) as refused:
        preflight(compose_cfg(*OVERLAP), check_space=False)
    assert refused.value.actors == ("child", "car_right")


def test_an_overlap_in_a_one_shot_frame_names_no_position(monkeypatch):
    """A one-shot scenario's frame has no position along a motion (nan): the refusal names the variant alone,
    never 'position nan' (the wide space's infeasible draws said it in every line)."""
    from garage_exp.core.errors import Infeasible
    from garage_exp.scenario import place

    monkeypatch.setattr(place, "clash", lambda poses, made, only: ("ego", "target"))
    with pytest.raises(Infeasible) as shot:
        place.check_overlaps({}, {}, "oneshot", float("nan"))
    assert "actors ego and target overlap (variant 'oneshot')" in str(shot.value) and "nan" not in str(shot.value)
    with pytest.raises(Infeasible, match=r"\(variant 'v', position 14\)"):
        place.check_overlaps({}, {}, "v", 14.0)
