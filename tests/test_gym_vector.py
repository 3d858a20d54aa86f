"""`garage_exp.gym.vector` (issue 34, item 3): the Gymnasium vector env steps K episodes of one case at once, their
frames rendered and detected as one batch. Env i sees what a lone StepOutEnv sees with the same actions (frames,
scores, rewards: the batch mixes no env's shot or camera noise into another's); an episode that ends is reset on
the next step (gymnasium's NEXT_STEP autoreset); spaces, infos and `gymnasium.make_vec` follow gymnasium 1.x.

QVGA, the step-out drive from 14 m by 1 m steps (at most 11 frames), the noisy camera model: each episode's noise
comes from its own stream, so a batch that shared one stream would change the scores."""

import numpy as np
import pytest

from conftest import require
from test_gym import FAST, store  # noqa: F401  (the module's migrated store fixture)

NOISY = [*FAST, "sensor=noisy"]
OUT = [1.0, -1.0]  # the child runs out at once, from one side of its gap: seen and confirmed in a few frames
HIDE = [-1.0, 1.0]  # the child stays deep between the cars: never decided, the whole drive


def overrides(store):
    return [*NOISY, f"tracking.uri={store[1]}"]


@pytest.fixture(scope="module")
def venv(store):
    require("vulkan", "vehicles", "models")
    from garage_exp.gym.vector import StepOutVectorEnv

    envs = StepOutVectorEnv(2, overrides=overrides(store))
    yield envs
    envs.close()


def env_row(infos: dict, i: int) -> dict:
    """Env i's frame table row from the vector infos (gymnasium's dict of arrays with `_key` masks)."""
    frame = infos["frame"]
    assert infos["_frame"][i]
    return {k: v[i].item() for k, v in frame.items() if not k.startswith("_")}


@pytest.mark.slow
def test_each_env_of_the_batch_is_a_lone_env(venv, store):
    """Two episodes with different actions, stepped as one batch: env by env, the observations, rewards,
    terminations and frame rows of a lone StepOutEnv (built on its own) given the same actions."""
    from garage_exp.gym.env import StepOutEnv

    actions = (OUT, HIDE)
    venv.reset(seed=0)
    seen: list[list] = [[], []]
    done = [False, False]
    while not all(done):
        obs, rewards, terminated, truncated, infos = venv.step(np.array(actions, dtype=np.float32))
        for i in range(2):
            if not done[i]:
                seen[i].append((obs[i].copy(), rewards[i], terminated[i], env_row(infos, i)))
                done[i] = bool(terminated[i] or truncated[i])
    assert len(seen[0]) < len(seen[1]) == 11  # one decided early, one the whole drive: ragged episodes
    lone = StepOutEnv(overrides=overrides(store))
    for i in range(2):
        lone.reset(seed=i)
        for obs, reward, terminated, row in seen[i]:
            o, r, te, _, info = lone.step(np.array(actions[i], dtype=np.float32))
            np.testing.assert_array_equal(o, obs)
            assert (r, te) == (reward, terminated)
            np.testing.assert_equal(info["frame"], row)
    assert {round(s[3]["composite"], 3) for s in seen[0]} != {0.0}  # the detectors saw something: no trivial match
    lone.close()


@pytest.mark.slow
def test_an_ended_episode_resets_on_the_next_step(venv):
    """NEXT_STEP autoreset: the step after env 0's episode ends, env 0 is reset (its action ignored, reward 0,
    not terminated, no frame) while env 1 steps on; env 0's next episode repeats the first one's first frame
    (the sensor stream starts again, seed + 1, as a job's)."""
    first_obs, _ = venv.reset(seed=0)
    _, _, _, _, infos = venv.step(np.array([OUT, HIDE], dtype=np.float32))
    first_row = env_row(infos, 0)
    steps = 1
    while True:
        _, _, terminated, _, infos = venv.step(np.array([OUT, HIDE], dtype=np.float32))
        steps += 1
        if terminated[0]:
            break
    assert not terminated[1] and infos["_episode_verdict"].tolist() == [True, False]
    assert infos["episode_verdict"]["renders"][0] == steps
    obs, rewards, terminated, truncated, infos = venv.step(np.array([[np.nan, np.nan], HIDE], dtype=np.float32))
    np.testing.assert_array_equal(obs[0], first_obs[0])
    assert rewards[0] == 0.0 and not terminated[0] and not truncated[0]
    assert infos["_frame"].tolist() == [False, True]  # env 1 stepped (its frame k = steps + 1), env 0 reset
    assert infos["frame"]["frame"][1] == steps + 1
    _, _, _, _, infos = venv.step(np.array([OUT, HIDE], dtype=np.float32))
    assert env_row(infos, 0) == first_row


@pytest.mark.slow
def test_spaces_infos_and_make_vec(venv, store):
    """Batched spaces and dtypes as gymnasium's; infos convert with gymnasium's DictInfoToList; the registered ids
    make the vector envs (`vector_entry_point`), PullOut's with its preset."""
    import gymnasium
    from gymnasium.vector import AutoresetMode
    from gymnasium.wrappers.vector import DictInfoToList

    from garage_exp.gym import ENV_ID, PULLOUT_ID
    from garage_exp.gym.vector import PullOutVectorEnv, StepOutVectorEnv

    assert venv.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    single = venv.single_observation_space
    assert venv.observation_space.shape == (2, *single.shape) and venv.observation_space.dtype == np.float32
    assert venv.action_space.shape == (2, 2) and venv.single_action_space == venv.world.action_space
    listed = DictInfoToList(venv)
    obs, infos = listed.reset(seed=3)
    assert obs.shape == (2, *single.shape) and obs.dtype == np.float32 and infos == [{}, {}]
    assert obs in venv.observation_space
    obs, rewards, terminated, truncated, infos = listed.step(venv.action_space.sample())
    assert obs in venv.observation_space and rewards.shape == (2,) and rewards.dtype == np.float64
    assert terminated.dtype == truncated.dtype == np.bool_ and terminated.shape == truncated.shape == (2,)
    assert [sorted(info["frame"]) == sorted(infos[0]["frame"]) for info in infos] == [True, True]

    made = gymnasium.make_vec(ENV_ID, num_envs=3, overrides=overrides(store))
    assert isinstance(made, StepOutVectorEnv) and made.action_space.shape == (3, 2) and len(made.envs) == 3
    made.close()
    made = gymnasium.make_vec(PULLOUT_ID, num_envs=2, overrides=overrides(store))
    assert isinstance(made, PullOutVectorEnv) and made.world.live.target == "car"
    assert made.action_space.shape == (2, 1)
    made.close()


@pytest.mark.slow
def test_stable_baselines3_trains_on_the_batch(venv):
    """`gym.envs=K`'s adapter (gym/sb3.py): SB3's VecEnv rules over the K episodes: an episode that ends is reset at
    once, its last observation in `terminal_observation`; PPO collects a rollout from both envs."""
    import copy

    from garage_exp.gym.sb3 import BatchedVecEnv
    from garage_exp.gym.train import make_ppo

    adapter = BatchedVecEnv(venv)
    first = adapter.reset()
    assert first.shape == (2, *venv.single_observation_space.shape)
    dones = [False, False]
    while not dones[0]:
        adapter.step_async(np.array([OUT, HIDE], dtype=np.float32))
        obs, rewards, dones, infos = adapter.step_wait()
    assert not dones[1] and "episode_verdict" in infos[0] and "terminal_observation" in infos[0]
    assert infos[0]["terminal_observation"][0] > 0  # the episode's last time
    np.testing.assert_array_equal(obs[0], first[0])  # env 0 already in its next episode
    cfg = copy.deepcopy(venv.world.cfg)
    cfg.gym.n_steps, cfg.gym.batch_size, cfg.gym.n_epochs = 2, 4, 1
    before = venv.renders
    make_ppo(adapter, cfg).learn(total_timesteps=4)
    assert venv.renders - before == 4  # two steps of two envs
