"""The gym entry point: check the config and build the environment (bad input: one line, exit 2, nothing
written), then `mode=train` (PPO, evaluated before and after, tracked in MLflow, the policy saved, its episodes
exported as a suite), `mode=check` (Gymnasium's env checker and one random episode) or `mode=export` (a saved
policy's episodes as a suite)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from garage_exp.core.plain import settings
from garage_exp.core import shell
from garage_exp.core.errors import GarageError, check_range
from garage_exp.gym import schema

COMMAND = shell.Command("garage_exp.gym", "gym", (schema.register,))


def check_gym(cfg: DictConfig) -> None:
    """`mode` and the `gym` node (the schema checked the types; keys forced past it are refused here)."""
    from garage_exp.core.schema_check import unknown_keys
    from garage_exp.gym.vector import MAX_ENVS

    gym = OmegaConf.to_container(cfg.gym, resolve=False)
    for path, key, owner in unknown_keys(gym, schema.AdversaryConf, ("gym",)):
        raise GarageError(f"unknown key {key!r} (not in {owner.__name__})", ".".join((*path, key)))
    if cfg.mode not in schema.MODES:
        raise GarageError(f"unknown mode {cfg.mode!r} ({' | '.join(schema.MODES)})", "mode")
    g = cfg.gym
    for key, hi in (("timesteps", 10**8), ("n_steps", 10**6), ("batch_size", 10**6), ("n_epochs", 1000),
                    ("eval_episodes", 10**5), ("per_band", 1000)):
        check_range(g[key], 1, hi, f"gym.{key}")
    check_range(g.seed, 0, 2**31 - 1, "gym.seed")
    check_range(g.envs, 1, MAX_ENVS, "gym.envs")
    check_range(g.learning_rate, 1e-8, 1.0, "gym.learning_rate")
    check_range(g.gamma, 0.0, 1.0, "gym.gamma")
    check_range(g.ent_coef, 0.0, 1.0, "gym.ent_coef")
    check_range(g.shaping, 0.0, 1.0, "gym.shaping")
    if cfg.mode == "export":
        if not g.policy:
            raise GarageError("mode=export needs a saved policy (gym.policy=.../policy.zip)", "gym.policy")
        if not Path(str(g.policy)).expanduser().is_file():
            raise GarageError("no such file", f"gym.policy={g.policy}")


# An episode's verdict the rates count (the objective's: `late`; a space's one-shot draws: `hard_fair`) -> its word.
WORDS = {"late": "late", "hard_fair": "hard"}


def verdict_key(env) -> str:
    """The episode record's key the rates and the learning curve count: the step-out env's `late` (as before), a
    space's draws the objective's verdict (space_env.py)."""
    return env.goal() if hasattr(env, "space") else "late"


def counted(rows: list[dict], key: str) -> tuple[int, int]:
    """(episodes with `key` true, episodes): a share of independent episodes, for its Wilson interval."""
    return sum(bool(r[key]) for r in rows), len(rows)


def suite_of(cfg: DictConfig, env, records: list[dict], root: Path) -> list[Path]:
    """The episodes as a suite: scenario files (export.py), or a space's draws as a manifest of reruns."""
    from garage_exp.gym import export

    if hasattr(env, "space"):
        return env.write_suite(records, root, int(cfg.gym.per_band))
    return export.write_suite(env.job, records, root, env.movers, int(cfg.gym.per_band))


TITLES = {"stepout": "PPO adversary: a child stepping out between parked cars",
          "pullout": "PPO adversary: a car pulling out of its bay"}


def learning_curve(rows: list[dict], before: tuple[int, int], after: tuple[int, int], path: Path,
                   case: str = "stepout", key: str = "late") -> Path:
    """Each training episode's return and the late rate over a moving window, with the late rate of the
    untrained and the trained policy's evaluation episodes ((late, episodes) each), shaded over its Wilson
    interval: a handful of episodes shows as a wide band, not as a line."""
    from garage_exp.results.stats import wilson

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    ret = np.array([r["return"] for r in rows], dtype=float)
    late = np.array([float(r[key]) for r in rows])
    word = WORDS.get(key, key)
    w = max(1, min(10, len(rows) // 4 or 1))
    fig, ax = plt.subplots(figsize=(7, 4.4))
    x = np.arange(len(rows))
    ax.plot(x, ret, ".", color="0.6", label="episode return")
    if len(rows) >= w:
        ax.plot(x[w - 1:], np.convolve(late, np.ones(w) / w, mode="valid"), "-", color="C3",
                label=f"{word} rate, last {w} episodes")
    for (k, n), colour, who in ((before, "C0", "untrained"), (after, "C2", "trained")):
        if not n:
            continue
        low, high = wilson(k, n)
        ax.axhline(k / n, color=colour, ls="--",
                   label=f"{word} rate {who} {k / n:.2f} ({k} of {n}; 95 % CI {low:.2f}-{high:.2f}, shaded)")
        ax.axhspan(low, high, color=colour, alpha=0.12, lw=0)
    ax.set_xlabel("training episode")
    ax.set_ylabel(f"return / {word} rate")
    ax.set_ylim(-0.05, max(1.05, float(ret.max()) + 0.1) if len(ret) else 1.05)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, fontsize=8, frameon=False)
    ax.set_title(TITLES.get(case, f"PPO adversary on case {case}"))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def rates_line(before: tuple[int, int], after: tuple[int, int], word: str = "late") -> str:
    """The late rate before and after training ((late, episodes) each), each with its Wilson interval, and, when
    Fisher's exact test cannot tell them apart, that it cannot: a few evaluation episodes prove nothing."""
    from garage_exp.results.stats import rate_text, rates_differ

    text = f"{word} rate {rate_text(*before)} untrained -> {rate_text(*after)} trained"
    p = rates_differ(*before, *after)
    if p != p:  # a side without episodes: no test was made, so no p-value is printed
        return text + "; no test (no episodes on one side)"
    return text if p < 0.05 else text + f"; no clear change at this many episodes (Fisher's exact p = {p:.2f})"


def run_train(cfg: DictConfig, env, out: Path, venv=None) -> dict:
    import pandas as pd

    from garage_exp.gym.train import train
    from garage_exp.results.stats import wilson
    from garage_exp.tracking import runs as tracking

    g = cfg.gym
    tags = {"kind": "gym", "case": str(cfg.case.name), "output_dir": str(out)}
    run = tracking.start_job_run(settings(cfg), f"adversary on {cfg.case.name}, {g.timesteps} steps, seed {g.seed}",
                                 tags, None)
    with tracking.tracked_run(run):  # ends FINISHED, or KILLED/FAILED with the error
        result = train(cfg, env, venv)
        rows = result["before"] + result["train"] + result["after"]
        table = pd.DataFrame(rows)
        table.to_csv(out / "episodes.csv", index=False)
        key = verdict_key(env)
        before, after, trained = (counted(result[k], key) for k in ("before", "after", "train"))
        for k, r in enumerate(result["train"]):
            run.log_metrics({"episode_return": r["return"], "episode_late": float(r[key]),
                             "episode_renders": r["renders"]}, step=k)
        summary = {"train_episodes": len(result["train"]), "renders": result["renders"], "wall_s": result["wall_s"]}
        if hasattr(env, "space"):  # a space's draws: how many its requirements (or overlaps) rejected unrendered
            summary.update(draws=env.draws, rejected=env.rejected)
        for name, (k, n) in (("late_rate_before", before), ("late_rate_after", after), ("train_late_rate", trained)):
            # each rate with its Wilson interval: a few evaluation episodes are a wide one
            low, high = wilson(k, n)
            summary.update({name: k / n if n else math.nan, f"{name}_low": low, f"{name}_high": high})
        run.log_metrics(summary)
        result["model"].save(out / "policy.zip")
        suite_root = Path(str(g.suite_dir)) if g.suite_dir else out / "suite"
        files = suite_of(cfg, env, result["after_full"], suite_root)
        figure = learning_curve(result["train"], before, after, out / "learning_curve.png", str(cfg.case.name), key)
        for path in (out / "episodes.csv", out / "policy.zip", figure):
            run.log_artifact(path)
        for path in files:
            run.log_artifact(path, "suite" if path.parent == suite_root else "suite/scenario")
    summary.update(run_id=run.run_id, policy=str(out / "policy.zip"), suite=str(suite_root))
    (out / "result.json").write_text(json.dumps(summary, indent=1))
    print(f"garage_exp.gym: {rates_line(before, after, WORDS.get(key, key))}; {len(result['train'])} training episodes, "
          f"{result['renders']} renders in {result['wall_s']:.0f} s; policy {out / 'policy.zip'}")
    if hasattr(env, "space") and env.draws:
        print(f"garage_exp.gym: {env.draws} draws of space {cfg.space.name}, {env.rejected} rejected before rendering "
              f"(acceptance {1 - env.rejected / env.draws:.2f})")
    return summary


def run_check(cfg: DictConfig, env) -> dict:
    from gymnasium.utils.env_checker import check_env

    check_env(env, skip_render_check=True)  # no render modes: the env renders for its detectors, not for people
    env.reset(seed=int(cfg.gym.seed))
    env.action_space.seed(int(cfg.gym.seed))
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        done = terminated or truncated
    v = info["episode_verdict"]
    if hasattr(env, "space"):  # a space's one-shot draw: hard or not, or rejected before rendering
        said = (f"rejected before rendering ({v['rejected']})" if v["rejected"] else
                f"difficulty {v['difficulty']:.2f}, {'hard' if v['hard_fair'] else 'not hard'}" if v["testable"]
                else "no fair frame")
        print(f"garage_exp.gym: the env checker passed; a random draw of space {cfg.space.name} "
              f"({env.action_space.shape[0]} factors): {v['renders']} frame(s), {said}, return {v['return']:.3f}")
        return {k: v[k] for k in ("hard_fair", "testable", "renders", "return", "rejected")}
    print(f"garage_exp.gym: the env checker passed; a random episode: {v['renders']} frames, "
          f"{'late' if v['late'] else 'in time' if v['testable'] else 'untestable'}, return {v['return']:.3f}")
    return {k: v[k] for k in ("late", "testable", "renders", "return")}


def run_export(cfg: DictConfig, env, out: Path) -> dict:
    from stable_baselines3 import PPO

    from garage_exp.gym.train import rollouts
    from garage_exp.results.stats import rate_text, wilson

    model = PPO.load(str(Path(str(cfg.gym.policy)).expanduser()), env=env, device="cpu")
    rows, full = rollouts(model, env, int(cfg.gym.eval_episodes), int(cfg.gym.seed) + 10_000, "export")
    root = Path(str(cfg.gym.suite_dir)) if cfg.gym.suite_dir else out / "suite"
    suite_of(cfg, env, full, root)
    key = verdict_key(env)
    k, n = counted(rows, key)
    low, high = wilson(k, n)
    print(f"garage_exp.gym: the policy's episodes: {WORDS.get(key, key)} rate {rate_text(k, n)}")
    return {"late_rate": k / n if n else math.nan, "late_rate_low": low, "late_rate_high": high, "suite": str(root)}


def main(cfg: DictConfig) -> dict:
    from garage_exp.gym.env import StepOutEnv
    from garage_exp.gym.vector import StepOutVectorEnv

    out = Path(HydraConfig.get().runtime.output_dir)
    check_gym(cfg)  # bad input: the shell removes the run dir and says it in one line
    if OmegaConf.select(cfg, "space.params", default=None):  # space=NAME: one-shot draws, its factors the action
        from garage_exp.gym.space_env import SpaceEnv

        env = SpaceEnv(cfg, list(HydraConfig.get().overrides.task))
        try:
            return run_check(cfg, env) if cfg.mode == "check" else (
                run_export(cfg, env, out) if cfg.mode == "export" else run_train(cfg, env, out))
        finally:
            env.close()
    # gym.envs > 1: PPO trains on K episodes at a time (one batch of frames a step); the evaluations and the
    # export play the vector env's world, a StepOutEnv like the lone one.
    venv = StepOutVectorEnv(int(cfg.gym.envs), cfg) if cfg.mode == "train" and int(cfg.gym.envs) > 1 else None
    env = venv.world if venv is not None else StepOutEnv(cfg)
    try:
        if cfg.mode == "check":
            return run_check(cfg, env)
        if cfg.mode == "export":
            return run_export(cfg, env, out)
        return run_train(cfg, env, out, venv)
    finally:
        env.close()
        if venv is not None:
            venv.close()


def cli(argv: list[str] | None = None) -> None:
    """`python -m garage_exp.gym overrides...`. Exit codes: 0 done; 2 bad input (one line, nothing written);
    1 a crash (traceback); 130 Ctrl-C, 143 SIGTERM (the training's run ends KILLED)."""
    COMMAND.run(main, argv)
