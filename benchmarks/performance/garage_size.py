"""Frame cost and peak memory against garage size: `python -m benchmarks.performance.garage_size [--frames 20] [--repeat 2]`.

Plans: research, realistic and the generated garages (garage_exp/plan/generate.py: garage13x15, its 2 x 2 version
garage26x30 and 3 x 3 version garage39x45, all in plans/), each with the default palette and palette=busy,
case 1. Each (plan, palette) runs in its own process (so its peak memory is its own), in rounds that alternate
the order, so a load spike from the other agents on the machine hits every plan alike. Inside a process the
render stage (render, silhouettes, ground truth, sensor: what grows with the garage; detection costs the same
per frame on every plan) runs `--frames` shots spread over the case with frustum culling on and off, alternating.

Columns: bodies (SAPIEN render bodies after merging static structure per material and tile), hidden (the
mean share the culled render hid as outside the frustum), s/frame culled and unculled (median over
repeats and rounds), cull gain, `x research` (culled s/frame over the research plan's with the same palette),
build s (description + SAPIEN load), peak MB (the render process's max RSS: SAPIEN, the scene, no detector).

Target (issue 13): garage26x30 with palette=busy <= 1.3x the research plan's per-frame cost.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import replace

from benchmarks import jobkit
from benchmarks.common import child_env

PLANS = ["research", "realistic", "garage13x15", "garage26x30", "garage39x45"]
PALETTES = ["default", "busy"]


def measure(plan: str, palette: str, frames: int, repeat: int) -> dict:
    t0 = time.perf_counter()
    job = jobkit.build_job([f"plan.name={plan}", f"palette={palette}", "case=1"])
    build = time.perf_counter() - t0  # includes the first frame (shader compile): reported apart below
    renderer = job.renderer.subs[0]  # the SAPIEN renderer of the job's render scene: its culling is measured
    shots = job.setup.shots
    job.setup = replace(job.setup, shots=shots[:: max(1, len(shots) // frames)][:frames])  # the whole approach
    n = len(job.setup.shots)
    times: dict[bool, list[float]] = {True: [], False: []}
    hidden = []
    for _ in range(repeat):
        for cull in (True, False):
            renderer.cull = cull
            start = time.perf_counter()
            for _item in job.frames(n):
                if cull:
                    hidden.append(renderer.culled / max(1, int(renderer.bodies.base.sum())))
            times[cull].append((time.perf_counter() - start) / n)
    renderer.cull = True
    t1 = time.perf_counter()
    renderer.load(job.scene)
    load = time.perf_counter() - t1
    return {"plan": plan, "palette": palette, "frames": n, "bodies": len(renderer.bodies.all),
            "entities": len(job.scene.entities), "hidden": statistics.mean(hidden), "culled": times[True],
            "unculled": times[False], "build": build, "load": load,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def run_child(plan: str, palette: str, args) -> dict:
    env = child_env()
    cmd = [sys.executable, __file__, "--child", plan, palette, "--frames", str(args.frames), "--repeat",
           str(args.repeat)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        print(proc.stderr[-3000:], file=sys.stderr)
        raise SystemExit(f"benchmark child failed ({plan}, {palette})")
    return json.loads(lines[-1][7:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--repeat", type=int, default=2, help="culled/unculled alternations inside a process")
    parser.add_argument("--rounds", type=int, default=2, help="passes over all plans, in alternating order")
    parser.add_argument("--plans", nargs="+", default=PLANS)
    parser.add_argument("--palettes", nargs="+", default=PALETTES)
    parser.add_argument("--child", nargs=2, metavar=("PLAN", "PALETTE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print("RESULT " + json.dumps(measure(*args.child, args.frames, args.repeat)), flush=True)
        return
    print(f"# scale, case 1, {args.frames} shots spread over the case, {args.repeat} repeats x {args.rounds} rounds; "
          f"{jobkit.machine()}")
    print(f"# before: {jobkit.load()}")
    configs = [(p, pal) for pal in args.palettes for p in args.plans]
    runs: dict[tuple[str, str], list[dict]] = {c: [] for c in configs}
    for r in range(args.rounds):
        for config in (configs if r % 2 == 0 else configs[::-1]):
            runs[config].append(run_child(*config, args))
            print(f"#   round {r + 1}: {config[0]} {config[1]} done; {jobkit.load()}", flush=True)
    rows = []
    for (plan, palette), results in runs.items():
        culled = statistics.median([t for res in results for t in res["culled"]])
        unculled = statistics.median([t for res in results for t in res["unculled"]])
        first = results[0]
        rows.append({"plan": plan, "palette": palette, "entities": first["entities"], "bodies": first["bodies"],
                     "hidden": statistics.mean(res["hidden"] for res in results), "culled": culled,
                     "unculled": unculled, "load": min(res["load"] for res in results),
                     "peak_mb": max(res["peak_mb"] for res in results)})
    base = {row["palette"]: row["culled"] for row in rows if row["plan"] == "research"}
    print(f"{'plan':>12} {'palette':>8} {'entities':>8} {'bodies':>6} {'hidden':>6} {'culled s':>8} "
          f"{'unculled s':>10} {'cull gain':>9} {'x research':>10} {'load s':>6} {'peak MB':>7}")
    for row in rows:
        ratio = row["culled"] / base[row["palette"]] if row["palette"] in base else float("nan")
        print(f"{row['plan']:>12} {row['palette']:>8} {row['entities']:>8} {row['bodies']:>6} "
              f"{row['hidden']:>6.0%} {row['culled']:>8.4f} {row['unculled']:>10.4f} "
              f"{1 - row['culled'] / row['unculled']:>9.0%} {ratio:>10.2f} {row['load']:>6.2f} "
              f"{row['peak_mb']:>7.0f}")
    target = next((r for r in rows if r["plan"] == "garage26x30" and r["palette"] == "busy"), None)
    if target and "busy" in base:
        ratio = target["culled"] / base["busy"]
        print(f"# target: garage26x30 busy / research busy = {ratio:.2f} per frame (goal <= 1.30: "
              f"{'met' if ratio <= 1.3 else 'NOT met'})")
    print(f"# after: {jobkit.load()}")


if __name__ == "__main__":
    main()
