"""cProfile of one job (case 1, bright, 66 frames): `python -m benchmarks.performance.profile_job [-o FILE]`.

Two runs, each in a fresh process as a user runs it (start-up included), outputs and MLflow in a temp dir:
  pipelined  the job as it runs now; the detectors work in a child process that cProfile does not see, so
             detection shows up only as the time the loop waits for it (`worker.py:result`)
  serial     GARAGE_EXP_DETECT_PROCESS=0: detection in-process, one frame after the other, so its own cost
             (OpenVINO, ultralytics' pre- and post-processing) is broken down
Writes the top 40 functions by cumulative time and the top 15 by own time of each to FILE
(benchmarks/results/profile_case1.md).
"""

from __future__ import annotations

import argparse
import datetime
import io
import os
import pstats
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks import jobkit
from benchmarks.common import RESULTS

JOB = ["case=1", "light=bright"]


def profile(tmp: Path, name: str, env_extra: dict[str, str]) -> tuple[str, float]:
    out = tmp / f"{name}.prof"
    env = {**os.environ, "YOLO_OFFLINE": "1", "TQDM_DISABLE": "1",
           "MLFLOW_TRACKING_URI": f"sqlite:///{tmp / 'mlflow.db'}", **env_extra}
    cmd = [sys.executable, "-m", "cProfile", "-o", str(out), "-m", "garage_exp", *JOB,
           f"hydra.run.dir={tmp / name}", "tracking.experiment=bench_profile"]
    proc = subprocess.run(cmd, env=env, cwd=jobkit.PROJECT_ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        print(proc.stdout[-2000:], proc.stderr[-3000:], file=sys.stderr)
        raise SystemExit(f"profiled job {name} failed")
    text = io.StringIO()
    stats = pstats.Stats(str(out), stream=text)
    total = stats.total_tt
    stats.strip_dirs().sort_stats("cumulative").print_stats(40)
    stats.sort_stats("tottime").print_stats(15)
    return _trim(text.getvalue()), total


def _trim(report: str) -> str:
    """pstats' report without its per-file header lines and blank runs."""
    lines = [ln.rstrip() for ln in report.splitlines() if not ln.strip().endswith(".prof")]
    out: list[str] = []
    for ln in lines:
        if ln or (out and out[-1]):
            out.append(ln)
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=RESULTS / "profile_case1.md")
    args = parser.parse_args()
    before = jobkit.load()
    with tempfile.TemporaryDirectory(prefix="garage_prof_") as d:
        runs = [(name, *profile(Path(d), name, env)) for name, env in
                (("pipelined", {}), ("serial", {"GARAGE_EXP_DETECT_PROCESS": "0"}))]
    header = [f"# cProfile of `python -m garage_exp {' '.join(JOB)}` (66 frames, start-up included)",
              f"# {datetime.date.today().isoformat()}; {jobkit.machine()}",
              f"# {before} before, {jobkit.load()} after"]
    body = []
    for name, report, total in runs:
        body += ["", f"## {name}: {total:.1f} s profiled", "", report]
    text = "\n".join(header + body)
    args.output.write_text(f"# cProfile of one case-1 job\n\nWritten by `python -m benchmarks.performance.profile_job`.\n\n"
                           f"```text\n{text}\n```\n")
    print("\n".join(header))
    for name, _, total in runs:
        print(f"{name}: {total:.1f} s profiled")
    print(f"written {args.output}")


if __name__ == "__main__":
    main()
