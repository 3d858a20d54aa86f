"""Training the adversary with stable-baselines3's PPO (no RL of our own), its evaluation before and after, and
`falsify`: the RL adversary as a falsification method, counting every render (training's included)."""

from __future__ import annotations

import copy
import math
import os
import time
from pathlib import Path

from omegaconf import DictConfig, open_dict
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger

from garage_exp.gym.env import StepOutEnv
from garage_exp.gym.vector import StepOutVectorEnv


def cpu_seconds(env: StepOutEnv) -> float:
    """CPU time of this process and of the detector's child (its detections are the episodes' cost too)."""
    total = time.process_time()
    pid = getattr(env.detector, "pid", None)
    if pid is not None:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime
        except (OSError, IndexError, ValueError):  # not Linux, or the child just restarted
            pass
    return total


def flat(record: dict, phase: str, episode: int, cpu_s: float) -> dict:
    """One episode as a table row: its verdict, its cost and its moves (per-frame lists left out)."""
    row = {"phase": phase, "episode": episode,
           **{k: v for k, v in record.items() if k not in ("values", "ego", "confidence", "params")},
           **{f"param.{k}": v for k, v in record["params"].items()}, "cpu_s": cpu_s}
    return row


class Episodes(BaseCallback):
    """Keeps each finished training episode's record (with its CPU time); stops the training after `stop_after`."""

    def __init__(self, env: StepOutEnv, stop_after: int | None = None):
        super().__init__()
        self.env, self.stop_after = env, stop_after
        self.records: list[dict] = []
        self.full: list[dict] = []
        self._cpu = None

    def _on_training_start(self) -> None:
        self._cpu = cpu_seconds(self.env)

    def _on_step(self) -> bool:
        for info, done in zip(self.locals["infos"], self.locals["dones"]):
            if done and "episode_verdict" in info:
                now = cpu_seconds(self.env)
                record = info["episode_verdict"]
                self.full.append(record)
                self.records.append(flat(record, "train", len(self.records), now - self._cpu))
                self._cpu = now
        return self.stop_after is None or len(self.records) < self.stop_after


def make_ppo(env, cfg: DictConfig) -> PPO:
    """PPO with an MLP policy on the state observation (env: a StepOutEnv, or sb3.BatchedVecEnv over K episodes),
    seeded; on the CPU with one thread (the renderer and the detector child have the other cores, and one thread
    keeps a seeded run repeatable)."""
    import torch

    torch.set_num_threads(1)
    g = cfg.gym
    model = PPO("MlpPolicy", env, n_steps=int(g.n_steps), batch_size=int(g.batch_size), n_epochs=int(g.n_epochs),
                learning_rate=float(g.learning_rate), gamma=float(g.gamma), ent_coef=float(g.ent_coef),
                seed=int(g.seed), device="cpu", verbose=0)
    # Our own callback records every episode; without a logger of its own, SB3's learn() makes a folder
    # SB3-<date> in the system's temp dir for every model and never removes it.
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def rollouts(model: PPO, env: StepOutEnv, episodes: int, seed: int, phase: str) -> tuple[list[dict], list[dict]]:
    """The policy's own episodes (actions sampled, as in training): (table rows, full records)."""
    rows, full = [], []
    for e in range(episodes):
        obs, _ = env.reset(seed=seed + e)
        cpu = cpu_seconds(env)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=False)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        record = info["episode_verdict"]
        full.append(record)
        rows.append(flat(record, phase, e, cpu_seconds(env) - cpu))
    return rows, full


def late_count(rows: list[dict]) -> tuple[int, int]:
    """(late episodes, episodes): a share of independent episodes, for its Wilson interval."""
    return sum(bool(r["late"]) for r in rows), len(rows)


def late_rate(rows: list[dict]) -> float:
    k, n = late_count(rows)
    return k / n if n else math.nan


def train(cfg: DictConfig, env: StepOutEnv, venv: StepOutVectorEnv | None = None) -> dict:
    """Evaluate the untrained policy, train, evaluate again: every episode's row and record, the model. venv: the
    K episodes PPO trains on as one batch (gym.envs), `env` its world, on which the evaluations play."""
    from garage_exp.gym.sb3 import BatchedVecEnv

    model = make_ppo(env if venv is None else BatchedVecEnv(venv), cfg)
    g = cfg.gym
    eval_seed = int(g.seed) + 10_000
    start = time.perf_counter()
    before, _ = rollouts(model, env, int(g.eval_episodes), eval_seed, "before")
    log = Episodes(env)
    model.learn(total_timesteps=int(g.timesteps), callback=log)
    after, after_full = rollouts(model, env, int(g.eval_episodes), eval_seed, "after")
    return {"model": model, "before": before, "train": log.records, "after": after, "after_full": after_full,
            "train_full": log.full, "wall_s": time.perf_counter() - start,
            "renders": env.renders + (venv.renders if venv is not None else 0)}


def falsify(cfg: DictConfig, seed: int, episodes: int) -> list[dict]:
    """`episodes` episodes of an adversary trained as it goes (PPO from scratch, seeded): one record per
    episode with its moves (`params`), `late`, `hard_fair`, `renders` and `cpu_s` (this process and the
    detector child). Every render counts: the episodes are the training's own."""
    cfg = copy.deepcopy(cfg)
    with open_dict(cfg):
        cfg.gym.seed = int(seed)
    env = StepOutEnv(cfg)
    model = make_ppo(env, cfg)
    log = Episodes(env, stop_after=int(episodes))
    model.learn(total_timesteps=10**9, callback=log)
    out = []
    for row, record in zip(log.records, log.full):
        out.append({"episode": row["episode"], "seed": int(seed), "params": dict(record["params"]),
                    "late": bool(record["late"]), "testable": bool(record["testable"]),
                    "hard_fair": bool(record["hard_fair"]), "difficulty": record["difficulty"],
                    "lateness": record["lateness"],
                    "detection_distance": record["detection_distance"], "renders": int(record["renders"]),
                    "cpu_s": float(row["cpu_s"]), "wall_s": float(record["wall_s"])})
    env.close()
    return out


# The benchmark's names for the adversary's moves: the step-out case's co-motion keys (its search space's).
BENCH_PARAMS = {"child.out.at": "case.motion.along.child.at", "child.out.speed": "case.motion.along.child.speed",
                "child.out.end": "case.motion.along.child.end", "child.offset": "case.actors.child.offset"}


def bench_records(overrides: list[str], definition: str, seed: int, episodes: int) -> list[dict]:
    """`falsify` on the gym config composed with `overrides`, rewarded for the benchmark's failure definition
    (`hard` or `late`), as the benchmark's trial records: params (the search space's keys), full_frames (the
    episode's renders), failure, value."""
    from garage_exp.gym.env import compose

    from garage_exp.search.objectives import gym_objectives

    cfg = compose([*overrides, f"gym.objective={definition}"])
    goal = gym_objectives()[definition]  # its verdict and value (search/objectives.py)
    out = []
    for r in falsify(cfg, seed, episodes):
        failure = r[goal.verdict]
        out.append({"params": {BENCH_PARAMS.get(k, k): v for k, v in r["params"].items()}, "state": "COMPLETE",
                    "screened": "", "full_frames": r["renders"], "cheap_frames": 0, "failure": bool(failure),
                    "value": r[goal.metric], "cpu_s": r["cpu_s"]})
    return out
