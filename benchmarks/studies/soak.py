"""Soak: N consecutive search trials in one process (issue 34): no crash, and memory that stays flat.

Runs the search (Hydra's sweeper `search`, trials launched in this process by search/launch.py) on case 1 of the
research plan at QVGA, two frames a trial, random sampler, and records after every trial the resident memory
(RSS) of this process and of the detector's child. Passes when every trial completed and this process's RSS
grew less than `--limit` MB (default 50) from the end of the warm-up (`--warmup` trials) to the end.

    nice -n 15 python -m benchmarks.studies.soak --trials 300 --out /tmp/soak.json
    python -m benchmarks.studies.soak --trials 10000 --out soak.json 'detector.models=[yolo11n_int8_openvino_model]'

Further arguments are Hydra overrides of the search (the second line scores one detector instead of three: the
soak checks the process, whose memory does not depend on how many models the detector's child holds).

The JSON holds the per-trial curve (trial, seconds since start, RSS MB, child RSS MB) and the verdict; the
docs (docs/performance.md) quote it with the command, commit, date and machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import ROOT
from benchmarks.common import SCENARIO, SPACE  # the search benchmark's scenario and space


def rss_mb(pid: int) -> float:
    import psutil

    try:
        return psutil.Process(pid).memory_info().rss / 2**20
    except psutil.Error:
        return float("nan")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=300)
    parser.add_argument("--warmup", type=int, default=20, help="trials before the baseline RSS is taken")
    parser.add_argument("--limit", type=float, default=50.0, help="allowed RSS growth after the warm-up, MB")
    parser.add_argument("--out", default="soak.json")
    parser.add_argument("overrides", nargs="*", help="more Hydra overrides of the search")
    opts = parser.parse_args()
    command = " ".join(["python -m benchmarks.studies.soak", *sys.argv[1:]])  # before Hydra rewrites sys.argv
    os.environ.setdefault("YOLO_OFFLINE", "1")

    from benchmarks.jobkit import machine
    from garage_exp.cli import app
    from garage_exp.core.state import STATE
    from garage_exp.search import launch

    curve: list[dict] = []
    start = time.perf_counter()
    real_call = launch.CachedLaunch.__call__

    def call(self, batch, idx):
        try:
            return real_call(self, batch, idx)
        finally:
            child = getattr(STATE.detector, "pid", None)  # the detector's child process, when there is one
            curve.append({"trial": len(curve), "s": round(time.perf_counter() - start, 2),
                          "rss_mb": round(rss_mb(os.getpid()), 1),
                          "child_rss_mb": round(rss_mb(child), 1) if child else None})
            if len(curve) % 10 == 0:
                print(json.dumps(curve[-1]), flush=True)
            if len(curve) % 500 == 0:  # a long soak stopped half-way still leaves its curve
                Path(opts.out).write_text(json.dumps({"command": command, "partial": True, "curve": curve}))

    launch.CachedLaunch.__call__ = call
    error = None
    with tempfile.TemporaryDirectory() as tmp:
        scenario = [o for o in SCENARIO if not o.startswith("case.motion.")]  # two frames a trial, not five
        argv = ["-m", "hydra/sweeper=search", *scenario, "case.motion.start=12", "case.motion.end=11",
                "camera.width=320", "camera.height=240", "renderer.save_frames=none", *SPACE,
                f"search.trials={opts.trials}", "search.sampler=random", "search.study=soak",
                f"search.storage=sqlite:///{tmp}/optuna.db", f"tracking.uri=sqlite:///{tmp}/mlflow.db",
                f"hydra.sweep.dir={tmp}/sweep", "hydra/job_logging=disabled", "hydra/hydra_logging=disabled",
                *opts.overrides]
        try:
            app.cli(argv)
        except SystemExit as exc:
            if exc.code:
                error = f"exit {exc.code}"
        except Exception as exc:  # the soak's verdict: any crash is a failure, written down
            error = f"{type(exc).__name__}: {exc}"
    base = curve[min(opts.warmup, len(curve)) - 1]["rss_mb"] if curve else float("nan")
    growth = curve[-1]["rss_mb"] - base if curve else float("nan")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    result = {"command": command, "commit": commit, "date": time.strftime("%Y-%m-%d %H:%M"),
              "machine": machine(), "trials_done": len(curve), "trials_asked": opts.trials,
              "error": error, "warmup": opts.warmup, "rss_after_warmup_mb": base, "rss_growth_mb": round(growth, 1),
              "limit_mb": opts.limit, "passed": error is None and len(curve) == opts.trials and growth < opts.limit,
              "curve": curve}
    Path(opts.out).write_text(json.dumps(result, indent=1))
    print(f"soak: {len(curve)}/{opts.trials} trials, RSS growth after warm-up {growth:+.1f} MB "
          f"(limit {opts.limit}), {'PASSED' if result['passed'] else 'FAILED'}")
    return 0 if result["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
