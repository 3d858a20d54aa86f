"""Sweep costs: start-up paid once, the joblib launcher's speed-up, peak memory per worker.

`python -m benchmarks.performance.sweep [--step 2.0]` runs, as a user would (`python -m garage_exp`):
  one   a single job (case 1, bright) in a fresh process
  basic the default 2x3 sweep `-m light=bright,dim case=1,2,3` with Hydra's basic launcher (one process)
  joblib the same sweep with `hydra/launcher=joblib hydra.launcher.n_jobs=2`
  ... serial  both sweeps again with GARAGE_EXP_DETECT_PROCESS=0 (the loop before issue 6), for comparison
`case.step` (default 2.0 instead of the cases' 0.5/1.0) cuts the frames so that this takes minutes; that
raises start-up's share, which only makes the ratios below harder to meet.

Targets (issue 6):
  start-up once  basic sweep <= 1.2 x (sum of the jobs' steady-state times) + one start-up. A job's duration is
                 its MLflow run's; steady-state is a warm job's: each job after the first as measured, the
                 first (cold) one replaced by its sibling of the same case with the other light (same frames).
                 Start-up = the single job's process wall time - that steady-state time.
  joblib         basic wall / joblib wall >= 1.7
  memory         peak RSS of a worker (Hydra's process for basic, each loky worker for joblib) plus its
                 detector child, sampled every 0.2 s, < 2 GB. A sum of RSS counts shared pages twice: an upper
                 bound.
Outputs and MLflow runs go to a temporary directory, not the project's store.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from benchmarks import jobkit
import psutil

SWEEP = ["light=bright,dim", "case=1,2,3"]


class Sampler(threading.Thread):
    """Peak RSS per worker (a worker and its descendants) of a process tree."""

    def __init__(self, root: int, interval: float = 0.2):
        super().__init__(daemon=True)
        self.root, self.interval = root, interval
        self.peak: dict[int, int] = {}  # worker pid -> peak bytes
        self.peak_total = 0
        self._done = threading.Event()

    def run(self) -> None:
        while not self._done.is_set():
            try:
                self._sample()
            except psutil.Error:
                pass
            self._done.wait(self.interval)

    def _sample(self) -> None:
        root = psutil.Process(self.root)
        workers = [p for p in root.children() if _is_worker(p)] or [root]
        total = _rss(root)
        for w in workers:
            rss = _rss(w) + sum(_rss(c) for c in w.children(recursive=True))
            if w.pid != root.pid:
                total += rss
            else:
                total = rss
            self.peak[w.pid] = max(self.peak.get(w.pid, 0), rss)
        self.peak_total = max(self.peak_total, total)

    def stop(self) -> None:
        self._done.set()
        self.join()


def _is_worker(p: psutil.Process) -> bool:
    try:
        cmd = " ".join(p.cmdline())
    except psutil.Error:
        return False
    return "loky" in cmd and "resource_tracker" not in cmd


def _rss(p: psutil.Process) -> int:
    try:
        return p.memory_info().rss
    except psutil.Error:
        return 0


def run(args: list[str], tmp: Path, name: str, env_extra: dict | None = None) -> tuple[float, Sampler]:
    env = {**os.environ, "YOLO_OFFLINE": "1", "TQDM_DISABLE": "1",
           "MLFLOW_TRACKING_URI": f"sqlite:///{tmp / 'mlflow.db'}", **(env_extra or {})}
    cmd = [sys.executable, "-m", "garage_exp", *args, f"hydra.run.dir={tmp / name}",
           f"hydra.sweep.dir={tmp / name}", f"tracking.experiment=bench_{name}"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, cwd=jobkit.PROJECT_ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    sampler = Sampler(proc.pid)
    sampler.start()
    out, _ = proc.communicate()
    wall = time.perf_counter() - t0
    sampler.stop()
    if proc.returncode != 0:
        print(out[-3000:], file=sys.stderr)
        raise SystemExit(f"{name} failed ({proc.returncode})")
    return wall, sampler


def job_durations(tmp: Path, name: str) -> list[tuple[str, float, int]]:
    """(run name, seconds, start ms) of each job run of an experiment, in start order."""
    import mlflow

    mlflow.set_tracking_uri(f"sqlite:///{tmp / 'mlflow.db'}")
    mlc = mlflow.MlflowClient()
    exp = mlc.get_experiment_by_name(f"bench_{name}")
    runs = [r for r in mlc.search_runs([exp.experiment_id], max_results=100)
            if "mlflow.parentRunId" in r.data.tags or name == "one"]
    runs = [r for r in runs if r.info.end_time and r.data.tags.get("case")]
    runs.sort(key=lambda r: r.info.start_time)
    return [(r.info.run_name, (r.info.end_time - r.info.start_time) / 1000.0, r.info.start_time) for r in runs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=float, default=2.0, help="case.step for every job (fewer frames)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-serial", action="store_true",
                        help="skip the two sweeps with the serial loop (GARAGE_EXP_DETECT_PROCESS=0)")
    args = parser.parse_args()
    extra = [f"case.step={args.step}"]
    print(f"# sweep {' '.join(SWEEP)} {' '.join(extra)}; {jobkit.machine()}")
    print(f"# before: {jobkit.load()}")
    with tempfile.TemporaryDirectory(prefix="garage_bench_") as d:
        tmp = Path(d)
        w_one, s_one = run(["case=1", "light=bright", *extra], tmp, "one")
        w_basic, s_basic = run(["-m", *SWEEP, *extra], tmp, "basic")
        joblib = ["hydra/launcher=joblib", f"hydra.launcher.n_jobs={args.workers}"]
        w_joblib, s_joblib = run(["-m", *SWEEP, *extra, *joblib], tmp, "joblib")
        serial = {}
        if not args.no_serial:  # the loop before issue 6, for comparison: detection in-process, no overlap
            off = {"GARAGE_EXP_DETECT_PROCESS": "0"}
            serial["basic"] = run(["-m", *SWEEP, *extra], tmp, "basic_serial", off)
            serial["joblib"] = run(["-m", *SWEEP, *extra, *joblib], tmp, "joblib_serial", off)
        one = job_durations(tmp, "one")
        basic = job_durations(tmp, "basic")
        in_joblib = job_durations(tmp, "joblib")
    print(f"{'job (basic sweep)':>28} {'seconds':>8}")
    for run_name, secs, _ in basic:
        print(f"{run_name:>28} {secs:>8.2f}")
    by_name = {n: s for n, s, _ in basic}
    first = basic[0][0]
    sibling = first.replace("light=bright", "light=dim") if "bright" in first else first.replace("dim", "bright")
    steady = {n: s for n, s, _ in basic}
    steady[first] = by_name.get(sibling, basic[0][1])
    startup = w_one - steady[first]
    total_steady = sum(steady.values())
    overhead = (w_basic - startup) / total_steady
    mem_basic = max(s_basic.peak.values()) / 2**30
    mem_joblib = max(s_joblib.peak.values()) / 2**30
    print(f"# single job: wall {w_one:.1f} s, its run {one[0][1]:.1f} s; steady-state of that job "
          f"{steady[first]:.1f} s (its sibling {sibling!r}); start-up {startup:.1f} s")
    print(f"{'target':>34} {'measured':>10} {'goal':>8} {'met':>4}")
    rows = [
        ("(basic - start-up) / sum(steady)", overhead, "<= 1.20", overhead <= 1.2),
        ("basic wall / joblib wall", w_basic / w_joblib, ">= 1.70", w_basic / w_joblib >= 1.7),
        ("peak GB per worker, basic", mem_basic, "< 2.00", mem_basic < 2.0),
        ("peak GB per worker, joblib", mem_joblib, "< 2.00", mem_joblib < 2.0),
    ]
    for label, value, goal, met in rows:
        print(f"{label:>34} {value:>10.2f} {goal:>8} {'yes' if met else 'NO':>4}")
    if serial:
        (wb, sb), (wj, sj) = serial["basic"], serial["joblib"]
        print(f"{'serial loop: basic / joblib':>34} {wb / wj:>10.2f} {'':>8} {'':>4}  (walls {wb:.1f} s, {wj:.1f} s; "
              f"peak GB per worker {max(sb.peak.values()) / 2**30:.2f}, {max(sj.peak.values()) / 2**30:.2f})")
        print(f"{'overlap gain, basic: serial/now':>34} {wb / w_basic:>10.2f}")
        print(f"{'overlap gain, joblib: serial/now':>34} {wj / w_joblib:>10.2f}")
    print(f"# sum of job runs: basic {sum(d for _, d, _ in basic):.1f} s, joblib {sum(d for _, d, _ in in_joblib):.1f} s "
          f"(two at a time: each job takes longer when it shares the cores)")
    print(f"# walls: one {w_one:.1f} s, basic {w_basic:.1f} s, joblib {w_joblib:.1f} s; sum of steady-state "
          f"{total_steady:.1f} s; peak total RSS basic {s_basic.peak_total / 2**30:.2f} GB, joblib "
          f"{s_joblib.peak_total / 2**30:.2f} GB")
    print(f"# after: {jobkit.load()}")


if __name__ == "__main__":
    main()
