"""`garage_exp.gym` (issue 23, item 2): the Gymnasium environment passes gymnasium's checker; its limits are the
action space's (no child runs at 20 km/h); a seeded PPO run repeats exactly; no reward for a target never fairly
visible before the critical distance, 1 for one seen but confirmed too late (hand-made frames); a static ego is
refused in one line with exit 2 and nothing written; a trained adversary is tracked and saved through the command
line, and its episodes export as a suite whose scenario a job composes and runs.

Everything runs at QVGA on the research plan (the step-out case needs a straight lane with bays: the tiny plan has
none), the ego's drive from 14 m by 1 m steps, so that an episode is at most 11 frames."""

import math

import numpy as np
import pytest

from conftest import require, run_app, run_in_process
from garage_exp.run.spec import scene_spec

FAST = ["camera.width=320", "camera.height=240", "detector.imgsz=320", "renderer.save_frames=none",
        "case.motion.start=14", "case.motion.step=1.0"]
HIDDEN = ["gym.movers=[{actor: child, key: out, low: -1.6, high: -1.5, start: -1.6}]"]  # deep between the cars


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    from conftest import seed_store

    tmp = tmp_path_factory.mktemp("gym")
    uri = f"sqlite:///{tmp / 'mlflow.db'}"
    seed_store([f"tracking.uri={uri}"], tmp)  # a migrated copy: the CLI's runs do not pay the migrations
    return tmp, uri


def make_env(store, *overrides):
    from garage_exp.gym.env import StepOutEnv, compose

    return StepOutEnv(compose([*FAST, f"tracking.uri={store[1]}", *overrides]))


@pytest.fixture(scope="module")
def env(store):
    require("vulkan", "vehicles", "models")
    return make_env(store)


def episode(env, action, seed=0):
    """One episode with a fixed action (or one drawn each step by `action()`): (rewards, the final info)."""
    env.reset(seed=seed)
    rewards, done, info = [], False, {}
    while not done:
        _, r, terminated, truncated, info = env.step(np.asarray(action() if callable(action) else action,
                                                                dtype=np.float32))
        rewards.append(r)
        done = terminated or truncated
    return rewards, info


@pytest.mark.slow
def test_env_checker_passes(env):
    import gymnasium
    from gymnasium.utils.env_checker import check_env

    from garage_exp.gym import ENV_ID

    assert ENV_ID in gymnasium.registry
    check_env(env, skip_render_check=True)
    # The registered id makes the same environment from overrides.
    made = gymnasium.make(ENV_ID, cfg=env.cfg)
    assert made.observation_space == env.observation_space and made.action_space == env.action_space
    assert env.action_space.shape == (2,) and env.dt == pytest.approx(1.0 / (10 / 3.6))
    assert [(m.name, m.rate) for m in env.movers] == [("child.out", 3.0), ("child.offset", 3.0)]


def test_limits_bound_every_action():
    """Whatever the actions, a child's value moves no faster than a child runs and speeds up no faster than a
    running start; 20 km/h (5.6 m/s) is refused as a limit, naming the key."""
    from garage_exp.core.errors import GarageError
    from garage_exp.scenario.schema import ActorConf
    from garage_exp.gym.limits import advance, resolve_movers
    from garage_exp.gym.schema import MoverConf

    actors = {"ego": ActorConf(role="ego"), "child": ActorConf(kind="person", age="child")}
    (m,) = resolve_movers([MoverConf("child", "out", -1.0, 2.5)], actors, ("out", "offset"))
    assert (m.rate, m.accel, m.start) == (3.0, 3.0, 0.0)
    rng = np.random.default_rng(0)
    value, velocity, dt = m.start, 0.0, 0.18
    for action in rng.uniform(-5, 5, 500):  # out-of-range actions too
        before = velocity
        value, velocity = advance(m, value, velocity, action, dt)
        assert m.low <= value <= m.high and abs(velocity) <= m.rate + 1e-9
        assert abs(velocity - before) <= m.accel * dt + 1e-9 or velocity == 0.0  # stopped at a bound
    with pytest.raises(GarageError, match=r"gym.movers.0.rate: 5.56 m/s is outside 0-3 m/s"):
        resolve_movers([MoverConf("child", "out", -1.0, 2.5, rate=5.56)], actors, ("out",))
    with pytest.raises(GarageError, match=r"gym.movers.0.actor: no actor 'ego' to move"):
        resolve_movers([MoverConf("ego", "distance", 0, 1)], actors, ("distance",))


def test_reward_on_hand_made_frames():
    """late.judge's verdict as the episode's: fair before the critical distance and never confirmed is late;
    a target never fairly visible before it is untestable, however badly it was detected."""
    from garage_exp.results.late import EgoConf
    from garage_exp.gym.reward import critical, episode

    ego = EgoConf()
    crit = critical(ego)

    def frames(fair_far: bool, hits: list[bool]):
        d = [12.0, 10.0, 8.0, 6.0, 4.0]
        return [{"frame": k + 1, "time": k * 0.36, "ego": d[k], "child.out": 0.0, "distance": d[k],
                 "composite": 0.9 if h else 0.1, "detected": h,
                 "fair": fair_far if d[k] > crit else True} for k, h in enumerate(hits)]

    missed = episode(frames(True, [False] * 5), ego, ["child.out"], crit, 0.0)
    assert missed["late"] and missed["testable"] and math.isnan(missed["detection_distance"])
    assert missed["hard_fair"] and missed["difficulty"] == pytest.approx(0.9)
    early = episode(frames(True, [True, True, False, False, False]), ego, ["child.out"], crit, 0.0)
    assert not early["late"] and early["detection_distance"] == 10.0
    inside = episode(frames(True, [False, False, False, True, True]), ego, ["child.out"], crit, 0.0)
    assert inside["late"] and inside["detection_distance"] == 4.0 < crit
    hidden = episode(frames(False, [False] * 5), ego, ["child.out"], crit, 0.0)
    assert not hidden["testable"] and not hidden["late"]
    # One fair peek before the critical distance, hidden again: no detector needing k=2 hits could have
    # confirmed it in time, so it is untestable (late.judge) and earns no reward.
    peek = frames(True, [False] * 5)
    for row in peek[:3]:  # fair at 6 m only before the critical distance (and at 4 m, inside it)
        row["fair"] = False
    peek = episode(peek, ego, ["child.out"], crit, 0.0)
    assert not peek["testable"] and not peek["late"]


@pytest.mark.slow
def test_no_reward_for_a_target_never_fairly_visible(store):
    """A child kept deep between the cars (the adversary may only move it there) is never confirmed - the
    detector never finds it - yet earns nothing: it was never a fair test."""
    require("vulkan", "vehicles", "models")
    env = make_env(store, *HIDDEN)
    rewards, info = episode(env, [1.0])
    verdict = info["episode_verdict"]
    assert verdict["renders"] == len(rewards) == 11  # the whole drive: nothing decided early
    assert not verdict["testable"] and not verdict["late"] and verdict["fair_frames"] == 0
    assert math.isnan(verdict["detection_distance"])  # never confirmed: a miss, but not a fair one
    assert sum(rewards) == 0.0


@pytest.mark.slow
def test_seeded_ppo_is_deterministic(env, tmp_path, monkeypatch):
    """Two short PPO trainings with one seed (an update half-way, so the second rollout is the trained
    policy's): the same actions and rewards, step for step; and no SB3 log folder left in the temp dir."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    from stable_baselines3.common.callbacks import BaseCallback

    from garage_exp.gym.train import make_ppo

    class Record(BaseCallback):
        def __init__(self):
            super().__init__()
            self.actions, self.rewards = [], []

        def _on_step(self):
            self.actions.append(np.array(self.locals["actions"]).copy())
            self.rewards.append(float(self.locals["rewards"][0]))
            return True

    import copy

    cfg = copy.deepcopy(env.cfg)
    cfg.gym.n_steps, cfg.gym.batch_size, cfg.gym.n_epochs, cfg.gym.seed = 4, 4, 2, 3
    runs = []
    for _ in range(2):
        model, rec = make_ppo(env, cfg), Record()
        model.learn(total_timesteps=8, callback=rec)  # two rollouts of 4 steps, an update between
        runs.append(rec)
    a, b = runs
    assert len(a.actions) == 8
    np.testing.assert_array_equal(np.concatenate(a.actions), np.concatenate(b.actions))
    assert a.rewards == b.rewards
    assert len({tuple(np.round(x.ravel(), 6)) for x in a.actions}) > 1  # a policy that acts, not a constant
    assert not list(tmp_path.glob("SB3-*"))  # SB3's default logger makes one per learn() and never removes it


def test_static_ego_is_refused(store, tmp_path):
    """ego.speed=0: one line naming the key, exit 2, no output dir left (checked before the scene is built)."""
    from garage_exp.gym.app import cli

    out = tmp_path / "run"
    r = run_in_process([*FAST, "ego.speed=0", f"tracking.uri={store[1]}", f"hydra.run.dir={out}"], tmp_path,
                       entry=cli)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("garage_exp.gym: ego.speed: a static ego"), lines
    assert not out.exists()


@pytest.mark.slow
def test_export_writes_a_suite_whose_scenario_runs(env, store, tmp_path):
    """Two episodes (a child that runs out at once: seen and confirmed; one that stays in the gap: untestable)
    export as a suite of the testable one; its scenario composes as a job's and reruns the episode's drive."""
    import pandas as pd
    import yaml

    from omegaconf import OmegaConf

    from garage_exp.gym.export import write_suite
    from garage_exp.openscenario.asam import validate

    rng = np.random.default_rng(3)  # a child running out at uneven speeds, from anywhere in its gap
    records = [episode(env, lambda: rng.uniform([0.3, -1.0], [1.0, 1.0]))[1]["episode_verdict"],
               episode(env, [-1.0, -1.0])[1]["episode_verdict"]]
    assert [r["testable"] for r in records] == [True, False]
    root = tmp_path / "suite"
    job = OmegaConf.merge(env.job, {"export": {"openscenario": True}})  # each scenario as OpenSCENARIO too
    files = write_suite(job, records, root, env.movers, per_band=2)
    manifest = pd.read_csv(files[0])
    assert len(manifest) == 1 and manifest.episode.tolist() == [0] and (root / "README.md").is_file()
    name = manifest.scenario[0]
    assert validate(root / "openscenario" / name / "scenario.xosc") == "OpenSCENARIO_1_2.xsd"
    assert validate(root / "openscenario" / name / "garage.xodr")
    text = (root / "scenario" / f"{name}.yaml").read_text()
    values = yaml.safe_load(text)
    assert values["case"]["motion"]["values"] == records[0]["ego"]
    assert values["case"]["actors"]["child"]["offset"] == pytest.approx(records[0]["values"]["child.offset"][0])
    r = run_app(["--config-dir", str(root), f"+scenario={name}", f"tracking.uri={store[1]}"], tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    table = pd.read_csv(tmp_path / "run" / "frames.csv")
    assert table.position.tolist() == records[0]["ego"]  # the episode's drive, frame for frame
    # The same frames, the same noise, the same detections: the episode's own confidences and verdict (issue 31).
    assert table.composite.tolist() == pytest.approx(records[0]["confidence"], abs=1e-6)
    verdict = pd.read_csv(tmp_path / "run" / "late.csv").iloc[0]
    assert (bool(verdict.late), bool(verdict.testable)) == (records[0]["late"], records[0]["testable"])


@pytest.mark.slow
def test_training_through_the_command_line(store, tmp_path):
    """`python -m garage_exp.gym` trains (a handful of steps), tracks the run in MLflow, saves the policy, writes
    every episode and the suite; the policy loads back for mode=export."""
    require("vulkan", "vehicles", "models")
    import json

    import mlflow

    from garage_exp.gym.app import cli

    out = tmp_path / "run"
    # a short drive (from 8 m: 6 frames an episode) and 4 steps: the command's bookkeeping, not the adversary, is
    # under test here
    short = ["case.motion.start=8", "case.motion.along.child.at=8"]
    args = [*FAST, *short, "gym.timesteps=4", "gym.n_steps=4", "gym.batch_size=4", "gym.n_epochs=1",
            "gym.eval_episodes=1", f"tracking.uri={store[1]}", f"hydra.run.dir={out}"]
    r = run_in_process(args, tmp_path, entry=cli)
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:])
    result = json.loads((out / "result.json").read_text())
    assert (out / "policy.zip").is_file() and (out / "suite" / "manifest.csv").is_file()
    client = mlflow.MlflowClient(tracking_uri=store[1])
    run = client.get_run(result["run_id"])
    assert run.info.status == "FINISHED" and run.data.params["gym.timesteps"] == "4"
    assert run.data.metrics["renders"] == result["renders"] > 4
    assert {a.path for a in client.list_artifacts(result["run_id"])} >= {"policy.zip", "episodes.csv",
                                                                          "learning_curve.png"}
    r = run_in_process([*FAST, *short, "mode=export", f"gym.policy={out / 'policy.zip'}", "gym.eval_episodes=1",
                        f"tracking.uri={store[1]}", f"hydra.run.dir={tmp_path / 'export'}"], tmp_path, entry=cli)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "export" / "suite" / "README.md").is_file()


def test_sigterm_ends_the_adversary_run_killed(store, tmp_path, monkeypatch):
    """SIGTERM during the training: the gym's MLflow run ends KILLED, the command exits 143 with one line (a bare
    traceback before). The environment and the training are stand-ins: the signal, not the training, is tested."""
    from conftest import run_statuses, seed_store, sigterm_here

    from garage_exp.gym import env as env_module
    from garage_exp.gym import train as train_module
    from garage_exp.gym.app import cli

    class NoEnv:
        def __init__(self, cfg):
            pass

        def close(self):
            pass

    monkeypatch.setattr(env_module, "StepOutEnv", NoEnv)
    monkeypatch.setattr(train_module, "train", sigterm_here)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    seed_store([f"tracking.uri={uri}"], tmp_path)
    r = run_in_process([*FAST, f"tracking.uri={uri}", f"hydra.run.dir={tmp_path / 'run'}"], tmp_path, entry=cli)
    assert r.returncode == 143, r.stderr[-2000:]
    assert r.stderr.strip().splitlines()[-1] == "garage_exp.gym: terminated (SIGTERM)"
    assert run_statuses(uri, "garage_gym") == ["KILLED"]


def test_gym_config_is_the_experiments_with_the_step_out_case():
    """conf/gym.yaml composes conf/config.yaml (a group or a default added there is here too), typed by GymConf,
    with the step-out case; an experiment's override works the same in both."""
    from conftest import compose_cfg
    from omegaconf import OmegaConf

    from garage_exp.gym.schema import GymConf

    gym = compose_cfg("light=dim", config="gym", hydra=True)
    job = compose_cfg("light=dim", "case=stepout", hydra=True)
    assert OmegaConf.get_type(gym) is GymConf and gym.mode == "train" and gym.tracking.experiment == "garage_gym"
    choices = {k: v for k, v in gym.hydra.runtime.choices.items() if not k.startswith(("hydra", "config_schema"))}
    assert choices == {k: v for k, v in job.hydra.runtime.choices.items()
                       if not k.startswith(("hydra", "config_schema"))}
    assert choices["case"] == "stepout" and choices["light"] == "dim"
    mine = {k: v for k, v in OmegaConf.to_container(gym).items() if k not in ("hydra", "gym", "mode", "tracking")}
    assert mine == {k: v for k, v in OmegaConf.to_container(job).items() if k not in ("hydra", "tracking")}
    # an adversary is no sweep of jobs: the experiment's sweep callback is not run for it
    assert gym.hydra.callbacks.mlflow_sweep._target_ == "hydra.experimental.callback.Callback"


@pytest.mark.slow
def test_bench_records_for_the_falsification_benchmark(env):
    """`garage_exp.gym.bench_records`: the benchmark's trial records, one per episode of an adversary trained as it
    goes, its moves named as the step-out search space's keys, every render counted."""
    from garage_exp.gym import bench_records

    records = bench_records(["plan=research", "case=stepout", *FAST], "late", seed=1, episodes=2)
    assert len(records) == 2
    for r in records:
        assert {"case.motion.along.child.at", "case.motion.along.child.speed", "case.motion.along.child.end",
                "case.actors.child.offset"} <= set(r["params"])
        assert 1 <= r["full_frames"] <= 11 and r["cheap_frames"] == 0 and r["cpu_s"] > 0
        assert isinstance(r["failure"], bool) and r["state"] == "COMPLETE"


# -- a car pulling out of its bay (case=pullout, garage_exp/PullOut-v0) ---------------------------------------------

PULLOUT_LENGTH = 4.7727  # the case's car, tcamryblue


def pullout_scene(*overrides):
    """case=pullout built as a job builds it (scenario/build.py): (classified plan, scene, shot list)."""
    from conftest import compose_cfg

    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.core.paths import PLANS_DIR
    from garage_exp.plan import classify, load_plan
    from garage_exp.scenario.assemble import build_scene

    cfg = compose_cfg("case=pullout", *overrides)
    classified = classify(load_plan(PLANS_DIR / f"{cfg.plan.name}.yaml"))
    return (cfg, classified,
            *build_scene(scene_spec(cfg), classified, VehicleLibrary(), np.random.default_rng(cfg.seed)))


def past_bay_line(site, bays, pose, length):
    """How far the front bumper of an actor `length` long at `pose` stands past its bay's line into the lane, and
    how far its centre is off the bay's axis."""
    from garage_exp.scenario.place import site_bay

    sb = site_bay(site, "bay", bays, "case.actors.car.bay")
    u, b = sb.facing, sb.bay
    along = (pose.x - b.x) * u[0] + (pose.y - b.y) * u[1]
    across = -(pose.x - b.x) * u[1] + (pose.y - b.y) * u[0]
    return along + length / 2 - b.depth / 2, across


def test_a_negative_gap_pulls_a_car_out_of_its_bay():
    """`gap` below 0: the front bumper that far past the bay line, straight out along the bay's axis, up to the
    car's whole length; a parked gap places as it always did; past the limit, one line naming the key."""
    require("vehicles")
    from dataclasses import replace

    from garage_exp.core.errors import GarageError
    from garage_exp.scenario.schema import ActorConf
    from garage_exp.scenario.place import pose_in_bay, site_bay
    from garage_exp.scenario.sites import find_site

    cfg, classified, _, _ = pullout_scene()
    site = find_site("straight_run", classified, cfg.garage)
    bays = {str(k): str(v) for k, v in cfg.case.bays.items()}
    car = ActorConf(bay="bay", gap=0.3)
    sb = site_bay(site, "bay", bays, "")
    parked = pose_in_bay(site, car, PULLOUT_LENGTH, bays, "case.actors.car")
    inset = sb.bay.depth / 2 - PULLOUT_LENGTH / 2 - 0.3  # the formula of every gap a bay held before
    assert (parked.x, parked.y) == (sb.bay.x + sb.facing[0] * inset, sb.bay.y + sb.facing[1] * inset)
    for gap in (0.3, 0.0, -0.5, -1.8, -PULLOUT_LENGTH):
        pose = pose_in_bay(site, replace(car, gap=gap), PULLOUT_LENGTH, bays, "case.actors.car")
        past, across = past_bay_line(site, bays, pose, PULLOUT_LENGTH)
        assert past == pytest.approx(-gap) and across == pytest.approx(0.0) and pose.yaw == parked.yaw
    with pytest.raises(GarageError) as refused:
        pose_in_bay(site, replace(car, gap=-5.5), PULLOUT_LENGTH, bays, "case.actors.car")
    message = str(refused.value)
    assert "\n" not in message and message.startswith("case.actors.car.gap: gap -5.5 m does not fit"), message
    assert "-4.77 m (pulled out into the lane by its whole length)" in message
    # A job's error names the case file and the co-motion's key that drove the car past its limit.
    with pytest.raises(GarageError) as refused:
        pullout_scene("case.motion.along.car.end=-6", "case.motion.along.car.at=20", "case.motion.along.car.speed=2")
    message = str(refused.value)
    assert "\n" not in message, message
    assert "pullout.yaml: case.motion.along.car.end: car's gap reaches -4.84 (frame 14): gap -4.84 m does not fit" \
        in message, message


def test_a_car_straight_out_of_its_bay_overlaps_only_what_is_in_the_lane():
    """A car pulled out by its whole length stays between its neighbours' sides: not refused for them; the ego
    driving past its tail still is (two cars overlapping)."""
    require("vehicles")
    from garage_exp.core.errors import GarageError

    out = ["case.motion.along.car.start=-4.77", "case.motion.along.car.end=-4.77"]
    _, _, _, setup = pullout_scene(*out, "case.motion.end=6")
    assert {round(s.poses["car"].y, 6) for s in setup.shots} == {round(setup.shots[0].poses["car"].y, 6)}
    with pytest.raises(GarageError, match=r"actors (ego and car|car and ego) overlap"):
        pullout_scene(*out, "case.motion.end=3")


def test_a_car_pulls_out_no_faster_than_a_car_may():
    """A vehicle's gap moves at most 2 m/s, speeding up at most 2 m/s^2; faster is refused naming the key."""
    from garage_exp.core.errors import GarageError
    from garage_exp.scenario.schema import ActorConf
    from garage_exp.gym.limits import advance, resolve_movers
    from garage_exp.gym.schema import MoverConf

    actors = {"ego": ActorConf(role="ego"), "car": ActorConf(bay="bay", gap=0.2)}
    (m,) = resolve_movers([MoverConf("car", "gap", -1.8, 0.2)], actors, ("gap",))
    assert (m.rate, m.accel, m.start) == (2.0, 2.0, 0.2)
    value, velocity = m.start, 0.0
    for _ in range(20):
        before = velocity
        value, velocity = advance(m, value, velocity, -1.0, 0.18)
        assert abs(velocity) <= 2.0 and abs(velocity - before) <= 2.0 * 0.18 + 1e-9 or velocity == 0.0
    assert value == -1.8
    with pytest.raises(GarageError, match=r"gym.movers.0.rate: 2.5 m/s is outside 0-2 m/s, what a vehicle can do"):
        resolve_movers([MoverConf("car", "gap", -1.8, 0.2, rate=2.5)], actors, ("gap",))
    with pytest.raises(GarageError, match=r"gym.movers.0.accel"):
        resolve_movers([MoverConf("car", "gap", -1.8, 0.2, accel=3.0)], actors, ("gap",))


def test_pull_out_bounds_are_checked_before_an_episode(store):
    """A mover's bound past the car's pull-out limit, or one that drives the car into the ego's path while the
    ego passes: refused when the environment is made, one line naming the mover."""
    require("vehicles", "models")
    from garage_exp.core.errors import GarageError
    from garage_exp.gym.env import PullOutEnv

    base = [*FAST, f"tracking.uri={store[1]}"]
    with pytest.raises(GarageError) as beyond:
        PullOutEnv(overrides=[*base, "gym.movers=[{actor: car, key: gap, low: -6, high: 0.2}]"])
    assert str(beyond.value).startswith("gym.movers.0.low: car.gap cannot be -6 (case.actors.car.gap: gap -6 m")
    with pytest.raises(GarageError, match=r"^gym.movers.0.low: car.gap at -3 puts ego and car in one another \(the "
                                          r"ego's distance 3\): it fits to -2\.\d+ \(give low: -2\.\d+, or null"):
        PullOutEnv(overrides=[*base, "gym.movers=[{actor: car, key: gap, low: -3, high: 0.2}]"])


@pytest.mark.slow
def test_pullout_env_checker_passes_and_the_car_pulls_out_within_its_limits(store):
    """garage_exp/PullOut-v0 passes the checker; an episode of full throttle out (action -1) puts the car's
    nose past the bay line at the first step, along the bay's axis, never faster than 2 m/s nor speeding up
    faster than 2 m/s^2, and stops at its bound, 1.8 m into the lane (a bound is a hard stop, as a person's)."""
    require("vulkan", "vehicles", "models")
    import gymnasium
    from gymnasium.utils.env_checker import check_env

    from garage_exp.gym import PULLOUT_ID

    assert PULLOUT_ID in gymnasium.registry
    env = gymnasium.make(PULLOUT_ID, overrides=[*FAST, f"tracking.uri={store[1]}", "gym.stop_when_decided=false"])
    env = env.unwrapped
    assert env.live.target == "car" and env.action_space.shape == (1,)
    assert [(m.name, m.low, m.high, m.start, m.rate, m.accel) for m in env.movers] == [
        ("car.gap", -1.8, 0.2, 0.2, 2.0, 2.0)]
    check_env(env, skip_render_check=True)
    _, info = episode(env, [-1.0])
    verdict = info["episode_verdict"]
    gaps = [0.2, *verdict["values"]["car.gap"]]
    assert verdict["renders"] == 11 and gaps[1] < 0 and gaps[-1] == pytest.approx(-1.8)
    speeds = np.diff(gaps) / env.dt
    assert np.all(speeds <= 1e-9) and np.all(np.abs(speeds) <= 2.0 + 1e-9)
    inside = int(np.argmax(np.isclose(gaps[1:], -1.8)))  # the steps before the car reaches its bound (and stops)
    assert inside >= 2 and np.all(np.abs(np.diff([0.0, *speeds[:inside]])) <= 2.0 * env.dt + 1e-9)
    _, poses = env._poses(env.drive[-1])  # the episode's last frame: the car's nose 1.8 m into the lane
    past, across = past_bay_line(env.live.site, env.live.bays, poses["car"], env.live.made["car"].extent[0])
    assert past == pytest.approx(1.8) and across == pytest.approx(0.0)


def test_the_late_rates_carry_their_intervals_and_a_tiny_run_says_it_proves_nothing():
    """Issue 31, item 10: "late rate 0.00 untrained -> 0.50 trained (2 episodes each)" had no interval."""
    from garage_exp.gym.app import rates_line

    tiny = rates_line((0, 2), (1, 2))
    assert tiny.startswith("late rate 0.00 (95 % CI 0.00-0.66, 0 of 2) untrained -> 0.50 (95 % CI 0.09-0.91, 1 of 2)")
    assert "no clear change at this many episodes (Fisher's exact p = 1.00)" in tiny
    clear = rates_line((0, 30), (20, 30))
    assert "0 of 30" in clear and "20 of 30" in clear and "no clear change" not in clear


def test_a_suite_readme_says_never_for_a_target_never_confirmed(tmp_path):
    """Issue 31, item 10: the README showed "nan" in its "confirmed at (m)" column."""
    import pandas as pd

    from garage_exp.gym.export import index_text

    table = pd.DataFrame([{"scenario": "hard_1", "band": "hard", "difficulty": 1.0, "late": True,
                           "detection_distance": math.nan, "critical_distance": 5.0},
                          {"scenario": "easy_1", "band": "easy", "difficulty": 0.1, "late": False,
                           "detection_distance": 9.04, "critical_distance": 5.0}])
    text = index_text(table, 2, 1)
    assert "| hard_1 | hard | 1.000 | yes | never | 5.0 |" in text  # (every export is exact: no `exact` column)
    assert "| easy_1 | easy | 0.100 | no | 9.0 | 5.0 |" in text and "nan" not in text
