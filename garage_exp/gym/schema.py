"""The schema of `python -m garage_exp.gym`'s config (conf/gym.yaml), registered in Hydra's ConfigStore.

The config is the experiment's (`Config`: plan, case, camera, detector, ego, ...) plus `gym` (the adversary, its
limits and its training) and `mode`, so every override a job takes (`plan=...`, `ego.speed=...`) works here too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from hydra.core.config_store import ConfigStore

from garage_exp.config import Config
from garage_exp.tracking.schema import TrackingConf

MODES = ("train", "check", "export")


@dataclass
class MoverConf:
    """One placement value of one actor that the adversary moves each step, within physical limits: the action
    (-1..1) is the value's velocity as a share of `rate`; `accel` caps how fast that velocity changes. With
    `once` the first step's action picks the value itself (low..high) and it is held: where a person stands.
    A bound left null is as far as the actor may stand (no two actors in one another: the job's rule); a bound
    given beyond that is refused (garage_exp/gym/limits.py `fit_bounds`)."""

    actor: str = "child"
    key: str = "out"  # a placement value (distance | offset | yaw | out | gap)
    low: Optional[float] = -1.0  # None: as far as the actor may stand (metres keys)
    high: Optional[float] = 2.0
    start: Optional[float] = None  # None: the case's own value
    rate: Optional[float] = None  # top speed of the value (m/s); None: the actor's physical top (limits.py)
    accel: Optional[float] = None  # top acceleration (m/s^2); None: the actor's physical top
    once: bool = False


@dataclass
class AdversaryConf:
    """The environment (garage_exp/gym/env.py), its reward and the PPO training (stable-baselines3)."""

    movers: list[MoverConf] = field(default_factory=lambda: [
        MoverConf("child", "out", -1.0, 2.5), MoverConf("child", "offset", None, None, once=True)])
    objective: str = "late"  # late: rewarded for a late detection | hard: for a hard-and-fair episode (>= 0.6)
    variant: int = 0  # which of the case's variants is the episode (its shown actors and target)
    shaping: float = 0.05  # x (1 - confidence) per fair frame before the critical distance; 0: only `late`
    stop_when_decided: bool = True  # objective late: end an episode once its verdict cannot change
    envs: int = 1  # episodes PPO trains on at a time (vector.py: their frames render and detect as one batch)
    timesteps: int = 1024  # PPO's training steps, all episodes together (each one a rendered, detected frame)
    n_steps: int = 128  # steps per PPO rollout and episode in flight (a rollout: n_steps x envs steps)
    batch_size: int = 32
    n_epochs: int = 4
    learning_rate: float = 3e-4
    gamma: float = 0.99
    ent_coef: float = 0.01
    seed: int = 0  # PPO's, the env's and the evaluation's seed
    eval_episodes: int = 8  # episodes of the untrained and of the trained policy (the late rate before/after)
    per_band: int = 2  # scenarios per difficulty band in the exported suite
    suite_dir: Optional[str] = None  # None: <output dir>/suite
    policy: Optional[str] = None  # mode=export: a saved policy (policy.zip) whose episodes are exported


@dataclass
class GymConf(Config):
    mode: str = "train"  # train | check (the env checker and one episode) | export (a saved policy's episodes)
    gym: AdversaryConf = field(default_factory=AdversaryConf)
    tracking: TrackingConf = field(default_factory=lambda: TrackingConf(experiment="garage_gym"))


def register() -> None:
    # conf/gym.yaml composes the experiment's config (conf/config.yaml) and types it with this subclass of Config.
    ConfigStore.instance().store(group="config_schema", name="gym", node=GymConf, package="_global_")
