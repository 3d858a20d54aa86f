"""`python -m garage_exp.gym space=wide` (issue 49 item 3): the gym reads a shipped space. Its action space is the
space's factors, one dimension each (counted here from conf/space/wide.yaml itself, not from the code under
test); a key the command fixes is no factor; a draw the space's requirements reject ends its episode unrendered
with reward 0; an accepted one renders its one frame and earns the hard objective's reward. At 160x120 (the
requirements' 25 px box then wants a near target)."""

import numpy as np
import pytest

from conftest import require

FAST = ["space=wide", "gym.objective=hard", "camera.width=160", "camera.height=120", "detector.imgsz=160",
        "detector.models=[yolo11n_int8_openvino_model]", "renderer.save_frames=none"]


def wide_factors() -> list[str]:
    """The searched keys of conf/space/wide.yaml, as Hydra's grammar reads its entries (a sweep: interval,
    choice, range)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    from garage_exp.core.paths import PROJECT_ROOT

    entries = [str(e) for e in OmegaConf.load(PROJECT_ROOT / "conf" / "space" / "wide.yaml").params]
    return [o.key_or_group for o in OverridesParser.create().parse_overrides(entries) if o.is_sweep_override()]


def test_decode_maps_the_box_onto_each_factors_range():
    import optuna.distributions as od

    from garage_exp.gym.space_env import decode

    params = {"a": od.FloatDistribution(4.0, 30.0), "b": od.IntDistribution(0, 999),
              "c": od.CategoricalDistribution(["x", "y", "z"]), "d": od.FloatDistribution(0.1, 10.0, log=True)}
    assert decode([-1, -1, -1, -1], params) == {"a": 4.0, "b": 0, "c": "x", "d": pytest.approx(0.1)}
    assert decode([1, 1, 1, 1], params) == {"a": 30.0, "b": 999, "c": "z", "d": pytest.approx(10.0)}
    mid = decode([0, 0, 0, 0], params)
    assert mid["a"] == 17.0 and mid["c"] == "y" and mid["d"] == pytest.approx(1.0)  # log range: geometric middle
    assert decode([5, -5, 0.2, 0], params)["a"] == 30.0  # out of the box: clipped to it


def action(env, **by_factor) -> np.ndarray:
    """An action with the named factors (their keys' last two parts, dots as __) set, the rest at 0 (middle)."""
    a = np.zeros(env.action_space.shape, dtype=np.float32)
    names = list(env.params)
    for short, u in by_factor.items():
        a[names.index("case.actors." + short.replace("__", "."))] = u
    return a


@pytest.mark.slow
def test_the_action_space_is_the_spaces_factors_and_a_draw_steps():
    require("vulkan", "vehicles", "models")
    from garage_exp.gym.space_env import SpaceEnv

    env = SpaceEnv(overrides=FAST)
    factors = wide_factors()
    assert len(factors) >= 20
    assert env.action_space.shape == (len(factors),) and list(env.params) == factors
    assert env.cfg.case.name == "oneshot" and env.cfg.plan.name.startswith("generated")
    assert env.require is not None and env.require.min_box == 25  # the space's requirements, settled

    # a near car beside a pillar off its line: accepted, one frame rendered, scored as the hard objective says
    near = action(env, target__type=-1.0, target__distance=-0.8, occluder__offset=1.0, occluder__gap=-1.0,
                  occluder__type=-1.0)
    obs, r, terminated, truncated, info = (env.reset(seed=0), *env.step(near))[1:]
    assert terminated and not truncated and "rejected" not in info
    (frame,) = info["frames"]
    v = info["episode_verdict"]
    assert frame["fair"] and v["fair_frames"] == 1 and env.renders == 1
    assert v["difficulty"] == pytest.approx(1.0 - frame["composite"], abs=1e-6)
    assert r == pytest.approx(0.05 * v["difficulty"] + float(v["difficulty"] >= 0.6))
    assert v["params"]["case.actors.target.type"] == "VWJetta_S1"
    assert v["params"]["case.actors.target.distance"] == pytest.approx(6.6)

    # the target 30 m away at the narrowest lens: its box is under 25 px at 160x120, rejected before rendering
    far = near.copy()
    far[list(env.params).index("case.actors.target.distance")] = 1.0
    far[list(env.params).index("camera.fovy")] = -1.0
    env.reset(seed=1)
    _, r, terminated, _, info = env.step(far)
    assert terminated and r == 0.0 and info["frames"] == [] and "box" in info["rejected"]
    assert env.renders == 1 and env.rejected == 1 and env.draws == 2  # never rendered


@pytest.mark.slow
def test_a_key_the_command_fixes_is_no_factor():
    require("vulkan", "vehicles", "models")
    from garage_exp.gym.space_env import SpaceEnv

    env = SpaceEnv(overrides=[*FAST, "camera.fovy=50"])
    assert "camera.fovy" not in env.params and env.action_space.shape == (len(wide_factors()) - 1,)
    assert float(env.cfg.camera.fovy) == 50.0


@pytest.mark.slow
def test_the_command_checks_the_space_env(tmp_path):
    """`python -m garage_exp.gym space=wide mode=check`: Gymnasium's env checker passes on the space's env and a
    random draw is said (rendered or rejected), nothing else run."""
    require("vulkan", "vehicles", "models")
    from conftest import run_in_process

    from garage_exp.gym.app import cli

    r = run_in_process([*FAST, "mode=check", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}",
                        f"hydra.run.dir={tmp_path / 'run'}"], tmp_path, entry=cli)
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"the env checker passed; a random draw of space wide ({len(wide_factors())} factors)" in r.stdout


@pytest.mark.slow
def test_training_on_the_space_counts_hard_draws_and_their_acceptance(tmp_path):
    """A tiny PPO run on space=wide through the command line: episodes.csv holds one draw an episode with its hard
    verdict and why a draw was rejected; the summary counts the draws and the rejected ones; the trained
    policy's draws go into a manifest of rerun commands."""
    require("vulkan", "vehicles", "models")
    import json

    import pandas as pd

    from conftest import run_in_process

    from garage_exp.gym.app import cli

    out = tmp_path / "run"
    r = run_in_process([*FAST, "gym.timesteps=4", "gym.n_steps=4", "gym.batch_size=4", "gym.eval_episodes=2",
                        f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}", f"hydra.run.dir={out}"], tmp_path,
                       entry=cli)
    assert r.returncode == 0, r.stderr[-2000:]
    episodes = pd.read_csv(out / "episodes.csv")
    assert list(episodes.phase.value_counts().sort_index()) == [2, 2, 4]  # after, before, train
    assert {"hard_fair", "rejected", "param.case.actors.target.distance"} <= set(episodes.columns)
    result = json.loads((out / "result.json").read_text())
    assert result["draws"] == 8 and result["rejected"] == episodes.rejected.notna().sum()
    assert "hard rate" in r.stdout and "draws of space wide" in r.stdout
    manifest = pd.read_csv(out / "suite" / "manifest.csv")
    assert list(manifest.columns) == ["scenario", "band", "difficulty", "episode", "command"]
