"""A sequential adversary for perception (issue 23): `python -m garage_exp.gym`.

`garage_exp/StepOut-v0` (env.py) is a Gymnasium environment: the ego drives a case's path and an adversary moves
a person within physical limits (limits.py) so that the detectors confirm it too late to stop (reward.py, on
garage_exp/results/late.py); `garage_exp/PullOut-v0` times a car pulling out of its bay instead (case=pullout).
Either is also a Gymnasium vector env (vector.py, `gymnasium.make_vec`): K episodes stepped as one batch.
A stable-baselines3 PPO agent learns it (train.py); a trained adversary's episodes export as scenario YAMLs and a
graded suite (export.py); `falsify` runs it for the falsification benchmark.
"""

from __future__ import annotations

import gymnasium

ENV_ID = "garage_exp/StepOut-v0"
PULLOUT_ID = "garage_exp/PullOut-v0"  # a car pulling out of its bay (case=pullout, the car's gap moved)

# gymnasium.make(ID, overrides=[...]) makes one environment; gymnasium.make_vec(ID, num_envs=K, overrides=[...])
# the vector env of vector.py (K episodes, their frames rendered and detected as one batch).
if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="garage_exp.gym.env:StepOutEnv",
                       vector_entry_point="garage_exp.gym.vector:StepOutVectorEnv")
if PULLOUT_ID not in gymnasium.registry:
    gymnasium.register(id=PULLOUT_ID, entry_point="garage_exp.gym.env:PullOutEnv",
                       vector_entry_point="garage_exp.gym.vector:PullOutVectorEnv")


def falsify(cfg, seed: int, episodes: int) -> list[dict]:
    """The RL adversary as a falsification method: one record per episode (see garage_exp/gym/train.py)."""
    from garage_exp.gym.train import falsify as run

    return run(cfg, seed, episodes)


def bench_records(overrides: list[str], definition: str, seed: int, episodes: int) -> list[dict]:
    """`falsify` as the falsification benchmark's trial records (garage_exp/gym/train.py)."""
    from garage_exp.gym.train import bench_records as run

    return run(overrides, definition, seed, episodes)


__all__ = ["ENV_ID", "PULLOUT_ID", "bench_records", "falsify"]
