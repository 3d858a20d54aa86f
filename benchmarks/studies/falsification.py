"""Does searching pay? Failures found per 1,000 full renders and per CPU-hour, by sampler, with and without the
pre-screen, on two scenarios and two failure definitions (issue 23, item 3).

Scenarios (each at least 4 factors):
- corner: case 1, the ego driving towards the corner whose pillar hides a car waiting beyond the bend;
- stepout: case stepout, a child stepping out between parked cars while the ego drives towards the gap.
Failure definitions:
- hard: the trial's difficulty over its fair frames is >= 0.6 (search.objective=difficulty);
- late: some trajectory of the trial was seen too late to stop (search.objective=late).
Each arm is one search (the product's own sweeper, in this process: the renderer and detector stay warm) of
`--trials` trials; a trial is a job of 9-10 frames at QVGA (320x240, detectors at 320). A failure counts only
when a full render found it; distinct failures cluster the failing trials in the unit-scaled factor space
(single linkage, `--radius`), so that one failure found 20 times counts once.

CPU time is this process's and its children's (the detector's process), per arm; the first search of each worker
(shader compilation, model loading) is a warm-up and not counted. Intervals: 95 % over seeds (t for the means,
a percentile bootstrap over seeds for ratios against random).

Run: .venv/bin/python -m benchmarks.studies.falsification [--seeds 5] [--trials 20] [--workers 2]
     [--methods random,qmc,tpe,cmaes,gp,tpe+pre,random+pre,rl] [--scenarios corner,stepout]
     [--definitions hard,late] [--resume]
Writes benchmarks/results/falsification.md (the tables) and outputs/benchmarks/falsification_records.json (every arm).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT

QVGA = ["camera.width=320", "camera.height=240", "detector.imgsz=320", "renderer.save_frames=none"]
SCENARIOS = {
    "corner": {
        "fixed": ["plan=research", "case=1", "palette.target_colours=[black]", "case.motion.start=12",
                  "case.motion.end=4", "case.motion.step=1.0", "case.actors.target.clip=true"],
        "space": ["light.intensity=interval(0.05,2.0)", "case.actors.target.distance=interval(2.0,10.0)",
                  "case.actors.target.offset=interval(-0.8,0.8)", "case.actors.target.yaw=interval(-90.0,90.0)",
                  "ego.speed=interval(5.0,20.0)"],
    },
    "stepout": {
        "fixed": ["plan=research", "case=stepout", "case.motion.start=12", "case.motion.step=1.0"],
        "space": ["case.motion.along.child.speed=interval(0.5,3.5)", "case.motion.along.child.at=interval(4.0,11.5)",
                  "case.motion.along.child.end=interval(0.5,3.0)", "light.intensity=interval(0.05,2.0)",
                  "ego.speed=interval(5.0,20.0)"],
    },
}
OBJECTIVE = {"hard": "difficulty", "late": "late"}
HARD = 0.6
STARTUP = 5  # random trials before TPE, GP and CMA-ES guide: a third of a 16-trial budget


def cpu_seconds() -> float:
    """CPU time of this process and its live children (the detector's process)."""
    import psutil

    me = psutil.Process()
    total = sum(me.cpu_times()[:2])
    for child in me.children(recursive=True):
        try:
            total += sum(child.cpu_times()[:2])
        except psutil.Error:
            pass
    return total


def search(argv: list[str]) -> None:
    from garage_exp.cli import app

    try:
        app.cli(["-m", "hydra/sweeper=search", *argv, "hydra/job_logging=disabled", "hydra/hydra_logging=disabled"])
    except SystemExit as exc:
        if exc.code not in (0, 1, None):  # 1: some trials failed; the study holds them (a cost, no failure)
            raise


def arm_argv(scenario: str, definition: str, method: str, seed: int, trials: int, store: Path) -> list[str]:
    sampler, _, pre = method.partition("+")
    return [*SCENARIOS[scenario]["fixed"], *QVGA, *SCENARIOS[scenario]["space"],
            f"search.objective={OBJECTIVE[definition]}", f"search.sampler={sampler}", f"search.seed={seed}",
            f"search.trials={trials}", f"search.startup={STARTUP}", f"search.prescreen.level={'detector' if pre else 'none'}",
            f"search.study={scenario}-{definition}-{method}-{seed}", f"search.storage=sqlite:///{store}/optuna.db",
            f"tracking.uri=sqlite:///{store}/mlflow.db", f"hydra.sweep.dir={store}/sweep-{time.time_ns()}",
            "search.top=1"]


def trial_records(store: Path, name: str, definition: str) -> list[dict]:
    import optuna
    from optuna.trial import TrialState

    study = optuna.load_study(study_name=name, storage=f"sqlite:///{store}/optuna.db")
    out = []
    for t in study.get_trials(deepcopy=False):
        full = t.state in (TrialState.COMPLETE, TrialState.PRUNED) and "screened" not in t.user_attrs
        if t.state == TrialState.COMPLETE:
            fail = (t.values[0] >= HARD) if definition == "hard" else (t.user_attrs.get("late") or 0) > 0
        else:
            fail = False
        out.append({"params": dict(t.params), "state": t.state.name, "screened": t.user_attrs.get("screened", ""),
                    "full_frames": int(t.user_attrs.get("frames", 0)) if full else 0,
                    "cheap_frames": int(t.user_attrs.get("prescreen_frames", 0)), "failure": bool(fail),
                    "value": t.values[0] if t.state == TrialState.COMPLETE else None})
    return out


def run_arm(task: tuple) -> dict:
    scenario, definition, method, seed, trials, store = task
    store = Path(store) / f"{scenario}-{definition}-{method}-{seed}"  # one store per arm: workers never share one
    store.mkdir(parents=True, exist_ok=True)
    start_cpu, start = cpu_seconds(), time.perf_counter()
    if method == "rl":
        records = rl_records(scenario, definition, seed, trials)
    else:
        argv = arm_argv(scenario, definition, method, seed, trials, store)
        search(argv)
        records = trial_records(store, f"{scenario}-{definition}-{method}-{seed}", definition)
    return {"scenario": scenario, "definition": definition, "method": method, "seed": seed,
            "cpu_s": cpu_seconds() - start_cpu, "wall_s": time.perf_counter() - start, "trials": records}


def safe_arm(task: tuple) -> dict:
    """run_arm, an arm's error reported instead of ending the benchmark."""
    try:
        return run_arm(task)
    except BaseException as exc:  # noqa: BLE001 - SystemExit from the CLI included
        return {"task": list(task), "error": f"{type(exc).__name__}: {exc}"[:500]}


def rl_records(scenario: str, definition: str, seed: int, episodes: int) -> list[dict]:
    """The RL adversary (garage_exp.gym, stable-baselines3 PPO), trained as it goes: its episodes as trials."""
    from garage_exp import gym as adversary

    return adversary.bench_records(SCENARIOS[scenario]["fixed"] + QVGA, definition, seed, episodes)


def warm_up(store: str) -> None:
    """A worker's first search: shaders compiled, models loaded; not counted."""
    os.environ.setdefault("YOLO_OFFLINE", "1")
    store = Path(store) / f"warm-up-{os.getpid()}"
    store.mkdir(parents=True, exist_ok=True)
    search(arm_argv("corner", "hard", "random", 999, 1, store))


def distinct(records: list[dict], space: list[str], radius: float) -> int:
    """Failing trials clustered in the unit-scaled factor space (single linkage at `radius`)."""
    from scipy.cluster.hierarchy import fcluster, linkage

    bounds = {}
    for item in space:
        key, _, rest = item.partition("=interval(")
        lo, hi = (float(v) for v in rest.rstrip(")").split(","))
        bounds[key] = (lo, hi)
    points = [[(r["params"][k] - lo) / (hi - lo) for k, (lo, hi) in bounds.items() if k in r["params"]]
              for r in records if r["failure"]]
    if len(points) < 2:
        return len(points)
    return int(fcluster(linkage(np.asarray(points), "single"), t=radius, criterion="distance").max())


def mean_ci(values: list[float]) -> tuple[float, float, float]:
    from scipy import stats

    a = np.asarray(values, dtype=float)
    m = float(a.mean())
    if len(a) < 2 or np.allclose(a, a[0]):
        return m, m, m
    h = float(stats.t.ppf(0.975, len(a) - 1) * a.std(ddof=1) / math.sqrt(len(a)))
    return m, m - h, m + h


def ratio_ci(a: list[float], b: list[float], draws: int = 5000, seed: int = 0) -> tuple[float, float, float]:
    """mean(a) / mean(b) with a percentile bootstrap over seeds (each resampled on its own)."""
    rng = np.random.default_rng(seed)
    a, b = np.asarray(a, float), np.asarray(b, float)
    point = a.mean() / b.mean() if b.mean() > 0 else math.inf
    ra = a[rng.integers(0, len(a), (draws, len(a)))].mean(1)
    rb = b[rng.integers(0, len(b), (draws, len(b)))].mean(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(rb > 0, ra / np.where(rb > 0, rb, 1), np.inf)
    # no interpolation: a resample in which random found nothing is an infinite ratio, not a NaN
    return (float(point), float(np.percentile(r, 2.5, method="inverted_cdf")),
            float(np.percentile(r, 97.5, method="inverted_cdf")))


def per_arm(arm: dict, radius: float) -> dict:
    trials = arm["trials"]
    full = sum(t["full_frames"] for t in trials)
    fails = sum(t["failure"] for t in trials)
    space = SCENARIOS[arm["scenario"]]["space"]
    return {"failures": fails, "distinct": distinct(trials, space, radius), "full_renders": full, "trials": len(trials),
            "cheap_renders": sum(t["cheap_frames"] for t in trials),
            "per_1000": 1000.0 * fails / full if full else 0.0,
            "distinct_per_1000": 1000.0 * distinct(trials, space, radius) / full if full else 0.0,
            "per_cpu_hour": 3600.0 * fails / arm["cpu_s"], "cpu_s": arm["cpu_s"],
            "screened": sum(t["screened"] == "easy" for t in trials),
            "infeasible": sum(t["state"] == "PRUNED" and t["screened"] != "easy" for t in trials)}


def fmt(ci: tuple[float, float, float], digits: int = 1) -> str:
    """A mean or ratio with its interval; a count's rate is never below 0 (a t interval over few seeds can be)."""
    m, lo, hi = ci
    if not math.isfinite(m):
        return "- (random found none)"
    return f"{m:.{digits}f} [{max(lo, 0.0):.{digits}f}, {hi:.{digits}f}]"


def tables(arms: list[dict], radius: float) -> list[str]:
    lines = []
    for scenario in dict.fromkeys(a["scenario"] for a in arms):
        for definition in dict.fromkeys(a["definition"] for a in arms):
            group = [a for a in arms if a["scenario"] == scenario and a["definition"] == definition]
            if not group:
                continue
            by = {}
            for a in group:
                by.setdefault(a["method"], []).append(per_arm(a, radius))
            lines += [f"### {scenario}, {definition} failures", "",
                      "| method | seeds | trials | screened / infeasible | failures (distinct) | per 1,000 full renders | "
                      "distinct per 1,000 | CPU s / trial | per CPU-hour | x random per CPU-hour |",
                      "|---|---|---|---|---|---|---|---|---|---|"]
            base = [r["per_cpu_hour"] for r in by.get("random", [])]
            best = None
            for method, rows in by.items():
                cpu = [r["per_cpu_hour"] for r in rows]
                ratio = ratio_ci(cpu, base) if base and method != "random" else None
                if ratio and math.isfinite(ratio[0]) and (best is None or ratio[0] > best[1][0]):
                    best = (method, ratio)
                trials = sum(r["trials"] for r in rows)
                lines.append(f"| {method} | {len(rows)} | {trials} | {sum(r['screened'] for r in rows)} / "
                             f"{sum(r['infeasible'] for r in rows)} | {sum(r['failures'] for r in rows)} "
                             f"({sum(r['distinct'] for r in rows)}) | {fmt(mean_ci([r['per_1000'] for r in rows]))} | "
                             f"{fmt(mean_ci([r['distinct_per_1000'] for r in rows]))} | "
                             f"{sum(r['cpu_s'] for r in rows) / trials:.2f} | {fmt(mean_ci(cpu))} | "
                             f"{fmt(ratio, 2) if ratio else '1'} |")
            if best:
                met = best[1][0] >= 3 and best[1][1] > 1
                lines += ["", f"Best per CPU-hour: {best[0]}, {fmt(best[1], 2)} x random; the goal (>= 3x, the "
                              f"interval above 1) is {'met' if met else 'not met'}."]
            lines.append("")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--trials", type=int, default=16)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--methods", default="random,qmc,tpe,cmaes,gp,tpe+pre")
    parser.add_argument("--scenarios", default="corner,stepout")
    parser.add_argument("--definitions", default="hard,late")
    parser.add_argument("--radius", type=float, default=0.15)
    parser.add_argument("--records", default=str(ROOT / "outputs" / "benchmarks" / "falsification_records.json"),
                        help="every arm's trials (large: kept out of the repository; the tables go to results/)")
    parser.add_argument("--tables-only", action="store_true", help="print the tables of a records file")
    parser.add_argument("--resume", action="store_true", help="keep the records file's arms, run the others")
    opts = parser.parse_args()
    os.environ.setdefault("YOLO_OFFLINE", "1")
    if opts.tables_only:
        arms = json.loads(Path(opts.records).read_text())
    else:
        arms = collect(opts)
    text = "\n".join([f"# studies/falsification.py, {time.strftime('%Y-%m-%d %H:%M')}, load {os.getloadavg()[0]:.1f}",
                      f"trials per arm {opts.trials}, radius {opts.radius}", "", *tables(arms, opts.radius)])
    print(text)
    (RESULTS / "falsification.md").write_text(text + "\n")
    return 0


def collect(opts) -> list[dict]:
    methods = opts.methods.split(",")
    tasks = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(opts.seeds):
            for scenario in opts.scenarios.split(","):
                for definition in opts.definitions.split(","):
                    for method in methods:
                        if method == "rl" and scenario != "stepout":
                            continue  # the adversary acts in the step-out scenario (garage_exp.gym)
                        tasks.append((scenario, definition, method, seed, opts.trials, tmp))
        path = Path(opts.records)
        path.parent.mkdir(parents=True, exist_ok=True)
        arms = json.loads(path.read_text()) if opts.resume and path.is_file() else []
        done = {(a["scenario"], a["definition"], a["method"], a["seed"]) for a in arms}
        tasks = [t for t in tasks if t[:4] not in done]
        with ProcessPoolExecutor(opts.workers, initializer=warm_up, initargs=(tmp,)) as pool:
            for arm in pool.map(safe_arm, tasks):
                if "error" in arm:
                    print(f"{arm['task'][:4]}: FAILED: {arm['error']}", flush=True)
                    continue
                arms.append(arm)
                path.write_text(json.dumps(arms))  # kept as it goes: a long run can be cut and tabled
                s = per_arm(arm, opts.radius)
                print(f"{arm['scenario']} {arm['definition']} {arm['method']} seed {arm['seed']}: "
                      f"{s['failures']} failures, {s['full_renders']} full renders, {arm['cpu_s']:.0f} CPU s",
                      flush=True)
    return arms


if __name__ == "__main__":
    sys.exit(main())
