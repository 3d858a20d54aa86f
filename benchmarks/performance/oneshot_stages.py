"""Where a one-shot scenario's time goes, stage by stage (issue 49, item 6): the one-shot benchmark's one-worker
search with a timer around each of the trial loop's stages, and each thread's CPU seconds, on this checkout and,
with `--before DIR`, on another checkout, the two alternated `--rounds` times; printed as milliseconds a call.

    python -m benchmarks.performance.oneshot_stages [--trials 200] [--warmup 16] [--rounds 2] [--before DIR]

No profiler: each stage is a function (STAGES) wrapped in perf_counter, counted after the first `--warmup` told
scenarios (shaders, the first loads of the garages and the detector's start are paid once per process). A stage
that a checkout does not have is left out of its run. The search is the one of `oneshot --space wide` (its
`child`: the wide space on `--garages` generated garages, the random sampler, seed 0, one worker), so every run
draws the same scenarios: the page gives each run's trial counts, which must agree. Threads are read from
/proc (Linux): the search's Python thread against lavapipe's render threads. An end-to-end rate, and its ratio
to today's search, is `oneshot`'s; this says which stages a change moved, where the end-to-end spread (5-10 %
between two runs of one arm) hides a few percent. The page: benchmarks/results/oneshot_stages.md.
"""

from __future__ import annotations

import argparse
import collections
import functools
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import RESULTS, ROOT, child_env

# (what it is, module, attribute): the trial loop's stages, then the parts of a rendered scenario's job.
STAGES = [
    ("a draw's requirement check", "garage_exp.search.loop", "SearchLoop.rejects"),
    ("its first look from plain data", "garage_exp.search.loop", "SearchLoop.plain_look"),
    ("Optuna's ask", "garage_exp.search.loop", "SearchLoop.next_trials"),
    ("a rendered scenario's job", "garage_exp.search.loop", "SearchLoop.run_batch"),
    ("the scene change", "garage_exp.render.sapien_backend", "SapienRenderer.load"),
    ("the pictures remade", "garage_exp.render.sapien_builder", "SceneBuilder.recolour"),
    ("line paint and lamps rebuilt", "garage_exp.render.sapien_builder", "SceneBuilder.replace_redrawn"),
    ("the actors and cameras replaced", "garage_exp.render.sapien_backend", "SapienRenderer._replace_actors"),
    ("the render (lit frame, silhouettes)", "garage_exp.render.batch", "RenderScene.render_batch"),
    ("the silhouettes", "garage_exp.render.sapien_backend", "SapienRenderer.unoccluded_ids"),
    ("the wait for detection", "garage_exp.perception.detect.worker", "DetectorProcess.result"),
    ("ground truth", "garage_exp.perception.groundtruth", "ground_truth"),
    ("sRGB conversions", "garage_exp.scene.textures", "srgb8"),
]


def thread_cpu() -> dict[str, float]:
    """CPU seconds (user + system) of this process's threads, by name without its number (llvmpipe-0, -1, ...:
    llvmpipe); {} where /proc has no tasks."""
    out: dict[str, float] = collections.Counter()
    tick = os.sysconf("SC_CLK_TCK")
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return {}
    for tid in tids:
        try:
            stat = Path(f"/proc/self/task/{tid}/stat").read_text()
        except OSError:
            continue  # ended meanwhile
        name = stat[stat.index("(") + 1:stat.rindex(")")].rstrip("0123456789:-_ ")
        fields = stat[stat.rindex(")") + 2:].split()
        out[name] += (int(fields[11]) + int(fields[12])) / tick
    return dict(out)


def child(trials: int, warmup: int, garages: int, out: str) -> int:
    """One run: the one-shot benchmark's wide-space search in this process with the stages timed after the
    warm-up; its counts, stages and threads' CPU to `out` as JSON."""
    from benchmarks.performance import oneshot
    from garage_exp.search import loop

    timing = {"on": False}
    spent: dict[str, list] = {}  # label -> [seconds, calls]

    def timed(label, fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                if timing["on"]:
                    spent.setdefault(label, [0.0, 0])
                    spent[label][0] += time.perf_counter() - start
                    spent[label][1] += 1
        return wrapper

    missing = []
    for label, module, attr in STAGES:
        try:
            owner = importlib.import_module(module)
            *path, name = attr.split(".")
            for part in path:
                owner = getattr(owner, part)
            setattr(owner, name, timed(label, getattr(owner, name)))
        except (ImportError, AttributeError):
            missing.append(label)  # an older checkout: this stage is not there

    told, cpu = [0], {}
    real_tell, real_run = loop.SearchLoop.tell, loop.SearchLoop.run

    def tell(self, trial, outcome, *args, **kwargs):  # a checkout's own tell may take more (its first attrs)
        real_tell(self, trial, outcome, *args, **kwargs)
        told[0] += 1
        if told[0] == warmup:
            cpu["warm"], cpu["warm_at"] = thread_cpu(), time.perf_counter()
            timing["on"] = True

    def run(self):
        ran = real_run(self)
        timing["on"] = False
        cpu["end"], cpu["end_at"] = thread_cpu(), time.perf_counter()
        return ran

    loop.SearchLoop.tell, loop.SearchLoop.run = tell, run
    oneshot.use_space("wide", garages)
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
        counts_path = fh.name
    code = oneshot.child("oneshot", trials, counts_path, warmup, [])
    counts = json.loads(Path(counts_path).read_text())
    os.unlink(counts_path)
    threads = {name: round(cpu["end"].get(name, 0.0) - cpu["warm"].get(name, 0.0), 2)
               for name in cpu.get("end", {})} if "warm" in cpu else {}
    Path(out).write_text(json.dumps({
        "code": code, "trials": counts["trials"], "complete": counts["complete"], "rejected": counts["rejected"],
        "told_timed": told[0] - warmup, "wall_timed": round(cpu.get("end_at", 0.0) - cpu.get("warm_at", 0.0), 2),
        "stages": spent, "missing": missing,
        "threads": {k: v for k, v in sorted(threads.items(), key=lambda kv: -kv[1]) if v >= 0.05}}))
    return code


def run_one(code: Path | None, trials: int, warmup: int, garages: int) -> dict:
    """One run in a child process on `code` (None: this checkout), as `oneshot` runs its arms."""
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
        out = fh.name
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "--trials", str(trials), "--warmup",
           str(warmup), "--garages", str(garages), "--out", out]
    done = subprocess.run(cmd, cwd=code or ROOT, env=child_env(code, GARAGE_EXP_PROVISIONED="1"),
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if done.returncode != 0:
        sys.stderr.write(done.stdout[-6000:])
        raise SystemExit(f"a run failed (exit {done.returncode})")
    result = json.loads(Path(out).read_text())
    os.unlink(out)
    return result


def table(runs: list[tuple[str, dict]]) -> list[str]:
    """The page's table: a stage a row (ms a call, and its calls), a run a column; then each run's counts, its
    timed wall seconds and its threads' CPU seconds."""
    lines = ["| stage (ms a call; calls) | " + " | ".join(label for label, _ in runs) + " |",
             "|---|" + "---|" * len(runs)]
    for label, _, _ in STAGES:
        cells = []
        for _, r in runs:
            seconds, calls = r["stages"].get(label, (0.0, 0))
            cells.append(f"{seconds / calls * 1e3:.1f}; {calls}" if calls else "-")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("| trials (complete, rejected) | " + " | ".join(
        f"{r['trials']} ({r['complete']}, {r['rejected']})" for _, r in runs) + " |")
    lines.append("| told after the warm-up; their wall s | " + " | ".join(
        f"{r['told_timed']}; {r['wall_timed']}" for _, r in runs) + " |")
    names = sorted({name for _, r in runs for name in r["threads"]}, key=lambda n: -max(
        r["threads"].get(n, 0.0) for _, r in runs))
    for name in names:
        lines.append(f"| thread {name}, CPU s | " + " | ".join(
            f"{r['threads'].get(name, 0.0):.2f}" for _, r in runs) + " |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200, help="scenarios a run (the study's budget)")
    parser.add_argument("--warmup", type=int, default=16, help="told scenarios left out at each run's start")
    parser.add_argument("--garages", type=int, default=16, help="generated garages drawn among")
    parser.add_argument("--rounds", type=int, default=2, help="before and this checkout alternated this many times")
    parser.add_argument("--before", type=Path, default=None, help="also runs on this checkout, alternated")
    parser.add_argument("--page", type=Path, default=RESULTS / "oneshot_stages.md")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    opts = parser.parse_args()
    if opts.child:
        return child(opts.trials, opts.warmup, opts.garages, opts.out)

    from benchmarks.jobkit import machine

    def commit(where: Path) -> str:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=where, capture_output=True,
                              text=True).stdout.strip()

    args = [("DIR" if a == str(opts.before) else a) for a in sys.argv[1:]]  # the page keeps no machine path
    runs = []
    for _ in range(opts.rounds):
        if opts.before is not None:
            runs.append((f"`{commit(opts.before)}`", run_one(opts.before, opts.trials, opts.warmup, opts.garages)))
        runs.append((f"`{commit(ROOT)}`", run_one(None, opts.trials, opts.warmup, opts.garages)))
    lines = ["# Where a one-shot scenario's time goes, stage by stage (issue 49, item 6)", "",
             f"`python -m benchmarks.performance.oneshot_stages {' '.join(args)}` · "
             f"{time.strftime('%Y-%m-%d %H:%M')} · {machine()}", "",
             f"The wide space on {opts.garages} generated garages, the random sampler, seed 0, one worker; "
             f"timed after {opts.warmup} told scenarios. Runs in the order they ran.", "", *table(runs)]
    gone = sorted({label for _, r in runs for label in r["missing"]})
    if gone:
        lines += ["", f"Not in every checkout (left out of those runs): {', '.join(gone)}."]
    opts.page.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
