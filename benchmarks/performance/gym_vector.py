"""The gym's vector env against the lone env, in one run: `python -m benchmarks.performance.gym_vector
[--steps 48] [--envs 1,2,4] [--seed 0] [overrides...]`.

StepOut-v0 on the research plan at QVGA (the gym tests' drive: from 14 m by 1 m steps), random actions (seeded):
env steps (rendered, detected frames) per second of a lone `StepOutEnv` and of `StepOutVectorEnv` with K episodes
(a vector step is K env steps, their frames one batch through the pipeline: on the CPU rendered one after another,
detection overlapping the next render). Each runs --steps env steps after a warm-up (the lone env: one episode; a
vector env: three steps); an autoreset renders nothing and counts for nothing. Prints a Markdown table with the
machine, the load before and after, and the commit.
"""

from __future__ import annotations

import argparse
import subprocess
import time

from benchmarks import jobkit
from benchmarks.common import ROOT

FAST = ["plan=research", "camera.width=320", "camera.height=240", "detector.imgsz=320", "renderer.save_frames=none",
        "case.motion.start=14", "case.motion.step=1.0"]


def lone_rate(cfg, steps: int, seed: int) -> float:
    """Env steps/s of one StepOutEnv (reset when an episode ends), after a warm-up episode."""
    from garage_exp.gym.env import StepOutEnv

    env = StepOutEnv(cfg)
    env.action_space.seed(seed)
    env.reset(seed=seed)
    done = False
    while not done:  # warm-up: the scene loaded, the detector child answering
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    rate = steps / (time.perf_counter() - t0)
    env.close()
    return rate


def vector_rate(cfg, k: int, steps: int, seed: int) -> float:
    """Env steps/s (frames) of a StepOutVectorEnv of `k` episodes, after three warm-up vector steps; only
    stepped envs' frames count (an autoreset renders nothing)."""
    from garage_exp.gym.vector import StepOutVectorEnv

    venv = StepOutVectorEnv(k, cfg)
    venv.action_space.seed(seed)
    venv.reset(seed=seed)
    for _ in range(3):
        venv.step(venv.action_space.sample())
    before, t0 = venv.renders, time.perf_counter()
    while venv.renders - before < steps:
        venv.step(venv.action_space.sample())
    rate = (venv.renders - before) / (time.perf_counter() - t0)
    venv.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=48)
    parser.add_argument("--envs", default="1,2,4")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    from garage_exp.core.state import STATE
    from garage_exp.gym.env import compose

    STATE.begin()
    cfg = compose([*FAST, *args.overrides])
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    print(f"# gym steps/s, StepOut-v0 QVGA, {args.steps} env steps each; {jobkit.machine()}; commit {commit}")
    print(f"# before: {jobkit.load()}")
    rows = [("lone StepOutEnv", lone_rate(cfg, args.steps, args.seed))]
    for k in (int(x) for x in args.envs.split(",")):
        rows.append((f"StepOutVectorEnv K={k}", vector_rate(cfg, k, args.steps, args.seed)))
    base = rows[0][1]
    print("| environment | env steps/s | against the lone env |\n|---|---|---|")
    for name, rate in rows:
        print(f"| {name} | {rate:.2f} | {rate / base:.2f}x |")
    print(f"# after: {jobkit.load()}")


if __name__ == "__main__":
    main()
