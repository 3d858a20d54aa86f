"""stable-baselines3's VecEnv over the gym's vector env (vector.py), so that PPO trains on K episodes at a time
whose frames render and detect as one batch (`gym.envs=K`). SB3 has its own VecEnv API: `step_wait` returns a
list of info dicts, and an episode that ends is reset at once, its last observation in the info's
`terminal_observation` (DummyVecEnv's rule); gymnasium's vector envs reset on the next step instead, so this
adapter steps the K episodes itself (`StepOutVectorEnv.advance`) and resets as SB3 does."""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from garage_exp.gym.vector import StepOutVectorEnv


class BatchedVecEnv(VecEnv):
    """SB3's VecEnv on `venv`'s K episodes (its own autoreset and seeds, none of the gymnasium vector env's)."""

    def __init__(self, venv: StepOutVectorEnv):
        self.venv = venv
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        obs = []
        for i, env in enumerate(self.venv.envs):
            options = {"options": self._options[i]} if self._options[i] else {}
            o, self.reset_infos[i] = env.reset(seed=self._seeds[i], **options)
            obs.append(o)
        self._reset_seeds()  # seeds and options are used once, as SB3's own VecEnvs use them
        self._reset_options()
        return np.stack(obs)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, -1)

    def step_wait(self):
        obs, rewards, dones, infos = [], np.zeros(self.num_envs, dtype=np.float32), np.zeros(self.num_envs, bool), []
        for i, (o, r, terminated, truncated, info) in enumerate(self.venv.advance(self._actions,
                                                                                  range(self.num_envs))):
            info = {**info, "TimeLimit.truncated": truncated and not terminated}
            rewards[i], dones[i] = r, terminated or truncated
            if dones[i]:
                info["terminal_observation"] = o
                o, self.reset_infos[i] = self.venv.envs[i].reset()
            obs.append(o)
            infos.append(info)
        return np.stack(obs), rewards, dones, infos

    def close(self) -> None:
        self.venv.close()

    def _targets(self, indices) -> list:
        return [self.venv.envs[i] for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices=None) -> list:
        return [getattr(env, attr_name) for env in self._targets(indices)]

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        for env in self._targets(indices):
            setattr(env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list:
        return [getattr(env, method_name)(*method_args, **method_kwargs) for env in self._targets(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._targets(indices)]  # the episodes are the bare environment's forks
