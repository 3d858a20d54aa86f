"""This checkout's render stage against another checkout's (the code before a change), same plans, one run:
`python -m benchmarks.performance.before --before /path/to/old/checkout [--frames 22] [--rounds 3]`.

Each (code, plan) runs case 1 with palette=busy in its own process (PYTHONPATH = that checkout), in rounds
that alternate the order, so load from other processes on the machine hits both alike. The render stage is
what a job's render loop does per frame (render, silhouettes, ground truth, sensor), over shots spread across
the case. Prints s/frame per code and plan, each plan's ratio to the research plan with the same code, and
whether the two codes rendered the same frames (colour and ground truth).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

from benchmarks import jobkit
from benchmarks.common import ROOT, child_env

PLANS = ["research", "garage26x30"]


def measure(plan_file: str, frames: int) -> dict:
    job = jobkit.build_job([f"plan.file={plan_file}", "palette=busy", "case=1"])
    shots = job.setup.shots
    job.setup = replace(job.setup, shots=shots[:: max(1, len(shots) // frames)][:frames])
    digest = hashlib.sha256()
    start = time.perf_counter()
    n = 0
    for item in job.frames():
        digest.update(item.rgb.tobytes())
        digest.update(repr(item.truth).encode())
        n += 1
    return {"s_per_frame": (time.perf_counter() - start) / n, "digest": digest.hexdigest()[:16]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, help="the other checkout (its garage_exp is used)")
    parser.add_argument("--frames", type=int, default=22)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--plans", nargs="+", default=PLANS)
    parser.add_argument("--child", nargs=1, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print("RESULT " + json.dumps(measure(args.child[0], args.frames)), flush=True)
        return
    if args.before is None:
        print("# bench_before: nothing to compare; give --before /path/to/another/checkout")
        return
    codes = {"before": str(args.before.resolve()), "now": str(ROOT)}
    print(f"# before/after, case 1, palette=busy, {args.frames} shots, {args.rounds} rounds; {jobkit.machine()}")
    print(f"# before = {codes['before']}; now = {codes['now']}; {jobkit.load()}")
    configs = [(c, p) for c in codes for p in args.plans]
    runs: dict[tuple[str, str], list[dict]] = {c: [] for c in configs}
    for r in range(args.rounds):
        for code, plan in (configs if r % 2 == 0 else configs[::-1]):
            env = child_env(codes[code])
            plan_file = str(ROOT / "plans" / f"{plan}.yaml")  # the plans of this checkout, for both
            proc = subprocess.run([sys.executable, __file__, "--child", plan_file, "--frames", str(args.frames),
                                   "--before", codes["before"]], env=env, capture_output=True, text=True,
                                  cwd=codes[code])
            lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
            if proc.returncode != 0 or not lines:
                print(proc.stderr[-3000:], file=sys.stderr)
                raise SystemExit(f"benchmark child failed ({code}, {plan})")
            runs[(code, plan)].append(json.loads(lines[-1][7:]))
            print(f"#   round {r + 1}: {code} {plan} {runs[(code, plan)][-1]['s_per_frame']:.4f} s/frame; "
                  f"{jobkit.load()}", flush=True)
    med = {c: statistics.median(x["s_per_frame"] for x in v) for c, v in runs.items()}
    print(f"{'code':>7} {'plan':>12} {'s/frame':>8} {'x research':>10} {'now/before':>10} {'same frames':>11}")
    for code, plan in configs:
        same = runs[("now", plan)][0]["digest"] == runs[("before", plan)][0]["digest"]
        print(f"{code:>7} {plan:>12} {med[(code, plan)]:>8.4f} {med[(code, plan)] / med[(code, 'research')]:>10.2f} "
              f"{med[(code, plan)] / med[('before', plan)]:>10.2f} {'yes' if same else 'NO':>11}")
    print(f"# after: {jobkit.load()}")


if __name__ == "__main__":
    main()
