"""The Gymnasium vector environments `garage_exp/StepOut-v0` and `garage_exp/PullOut-v0` (issue 34, item 3): K
episodes of one case stepped at once, their frames rendered and detected as one batch.

    envs = gymnasium.make_vec("garage_exp/StepOut-v0", num_envs=4, overrides=["camera.width=320", ...])

One world: the vector env builds ONE StepOutEnv (one preflight, one scene, one LiveScenario, one set of movers and
limits) and keeps K forks of it (`StepOutEnv.fork`), each with its own episode state and sensor stream. Env i
sees exactly the frames, scores and rewards a lone StepOutEnv would with the same actions: each episode draws its
camera noise from its own stream (the job's seed + 1, frame after frame), and a shot poses every moved actor.

A step: each env moves its movers and makes its shot; the K shots go through the frame pipeline as one batch
(`env.shoot` -> `FramePipeline.detect_shots`), which hands them to the render scene's one call,
`render.batch.RenderScene.render_batch`, as many at a time as it has sub-scenes; each env then judges its frame
(`StepOutEnv.finish`). The envs' pipeline is over the render scene a job of their config opens
(`render.open.open_renderer`: `renderer.scenes` sub-scenes, 1 by default): on the CPU the batch's shots are posed
and rendered one after another while the detector child works on the previous frame (detection overlaps
rendering, as in a job); `renderer.scenes=K` under `renderer.device=cuda` takes the same call whole, as one
RenderSystemGroup picture (unmeasured: no GPU was lent to the sessions that wrote it).

Autoreset is gymnasium's NEXT_STEP: the step after an env's episode ended resets that env (its action ignored,
reward 0, not terminated) and returns its first observation. Infos are gymnasium's dict of arrays with `_key`
masks: `frame` (each stepped env's frame table row) and `episode_verdict` (set where an episode ended).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from omegaconf import DictConfig

from garage_exp.core.errors import GarageError
from garage_exp.gym.env import PullOutEnv, StepOutEnv, shoot

MAX_ENVS = 256  # episodes in flight: far beyond what one CPU renders well, within what a GPU's group holds


class StepOutVectorEnv(VectorEnv):
    """`num_envs` episodes of the step-out adversary's environment (`cfg`: a composed gym config, or `overrides`
    to compose one, as StepOutEnv takes them). `world` is the one StepOutEnv built; `envs` its forks."""

    ENV = StepOutEnv
    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int, cfg: DictConfig | None = None, overrides: list[str] | tuple[str, ...] = ()):
        if not 1 <= int(num_envs) <= MAX_ENVS:
            raise GarageError(f"{num_envs} environments: give 1 to {MAX_ENVS}", "num_envs")
        self.world = self.ENV(cfg, overrides)
        self.num_envs = int(num_envs)
        self.envs = [self.world.fork() for _ in range(self.num_envs)]
        self.single_observation_space = self.world.observation_space
        self.single_action_space = self.world.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._obs = np.zeros(self.observation_space.shape, dtype=self.observation_space.dtype)
        self._rewards = np.zeros(self.num_envs, dtype=np.float64)
        self._terminated = np.zeros(self.num_envs, dtype=np.bool_)
        self._truncated = np.zeros(self.num_envs, dtype=np.bool_)
        self._autoreset = np.zeros(self.num_envs, dtype=np.bool_)

    @property
    def renders(self) -> int:
        """Frames rendered and detected by the K episodes, all episodes."""
        return sum(env.renders for env in self.envs)

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        """Every env's new episode, or those in `options["reset_mask"]` (a bool array of shape (K,)). seed: an
        int gives env i seed + i (as gymnasium's SyncVectorEnv), or one per env."""
        super().reset(seed=seed if isinstance(seed, int) else None)
        seeds = [seed + i for i in range(self.num_envs)] if isinstance(seed, int) else (
            [None] * self.num_envs if seed is None else list(seed))
        if len(seeds) != self.num_envs:
            raise ValueError(f"{len(seeds)} seeds for {self.num_envs} environments")
        options = dict(options or {})
        mask = np.asarray(options.pop("reset_mask", np.ones(self.num_envs, dtype=np.bool_)))
        if mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
            raise ValueError(f"options['reset_mask'] must be a bool array of shape ({self.num_envs},)")
        infos: dict = {}
        for i in np.flatnonzero(mask):
            self._obs[i], info = self.envs[i].reset(seed=seeds[i], options=options or None)
            infos = self._add_info(infos, info, i)
        self._terminated[mask] = self._truncated[mask] = self._autoreset[mask] = False
        return self._obs.copy(), infos

    def step(self, actions):
        """Each env's step (actions: (K, n_movers)); an env whose episode ended at the last step is reset instead
        (NEXT_STEP autoreset). The stepped envs' frames render and detect as one batch (`advance`)."""
        actions = np.asarray(actions, dtype=np.float32).reshape(self.action_space.shape)
        infos: dict = {}
        stepping = []
        for i, env in enumerate(self.envs):
            if self._autoreset[i]:
                self._obs[i], info = env.reset()
                self._rewards[i], self._terminated[i], self._truncated[i] = 0.0, False, False
                infos = self._add_info(infos, info, i)
            else:
                stepping.append(i)
        for i, (obs, r, terminated, truncated, info) in zip(stepping, self.advance(actions, stepping)):
            self._obs[i], self._rewards[i], self._terminated[i], self._truncated[i] = obs, r, terminated, truncated
            infos = self._add_info(infos, info, i)
        self._autoreset = self._terminated | self._truncated
        return self._obs.copy(), self._rewards.copy(), self._terminated.copy(), self._truncated.copy(), infos

    def advance(self, actions: np.ndarray, indices: Sequence[int]) -> list[tuple]:
        """One step of each env in `indices` (row i of `actions` is env i's), whose episodes are under way: all
        move, their frames go through the pipeline as one batch, each judges its own: (observation, reward,
        terminated, truncated, info) per env, in `indices`' order. No autoreset here (the callers' rule: step's,
        or stable-baselines3's in sb3.py)."""
        envs = [self.envs[i] for i in indices]
        for i, env in zip(indices, envs):
            env.move(actions[i])
        return [env.finish(row) for env, row in zip(envs, shoot(envs))]

    def close_extras(self, **kwargs) -> None:
        for env in (*self.envs, self.world):
            env.close()


class PullOutVectorEnv(StepOutVectorEnv):
    """`garage_exp/PullOut-v0`'s vector env: K episodes of a car pulling out of its bay (PullOutEnv's preset,
    `overrides` after it)."""

    ENV = PullOutEnv
