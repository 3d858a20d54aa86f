"""The search's throughput and what a search buys over a grid (issue 10, §5).

1. Trials per hour for 5-frame trials on the research plan (case 1, one target colour, five ego positions),
   and the share of the trials' wall time that is neither the render stage (each frame's lit picture,
   silhouettes, ground truth and sensor model) nor waiting for the detector: Hydra, MLflow, Optuna, the scene's
   set-up, the trial's table and picture. The first trial (shader compilation,
   model loading) is left out: it is paid once per worker.
2. Search against grid on the same budget of trials (so of frames): TPE's hardest fair scenario against the
   hardest cell of a grid over the same ranges (`search.sampler=grid`, 3 levels a factor), for several TPE
   seeds (one search is one draw).

Run: .venv/bin/python -m benchmarks.studies.search [--trials 40] [--levels 3] [--seeds 3] [--skip-grid]
[--skip-throughput]
Everything goes to a temporary store; the table is printed and written to benchmarks/results/search.md (--out).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import RESULTS

# Case 1 as in the study of docs/results.md: the ego 12 to 10 m before the corner (5 frames), the black target
# beyond the corner's pillar; three continuous factors, so that a grid of 3 levels is 27 trials.
SCENARIO = ["plan=research", "case=1", "palette.target_colours=[black]", "case.motion.start=12", "case.motion.end=10",
            "case.actors.target.clip=true"]  # a distance below the target's room (2.6 m) trimmed to it, as measured
SPACE = ["light.intensity=interval(0.1,1.0)", "case.actors.target.distance=interval(2.0,10.0)",
         "case.actors.target.yaw=interval(-90.0,90.0)"]


class Timers:
    """Seconds spent rendering and waiting for the detector, per trial (wrapping the calls in place)."""

    def __init__(self):
        self.render = self.detect = 0.0
        self.trials: list[tuple[float, float, float, float]] = []  # start, end, render, detect

    def wrap(self, owner, name: str, field: str):
        real = getattr(owner, name)

        def timed(*args, **kwargs):
            t = time.perf_counter()
            try:
                return real(*args, **kwargs)
            finally:
                setattr(self, field, getattr(self, field) + time.perf_counter() - t)

        setattr(owner, name, timed)

    def install(self):
        from garage_exp.run import frames as experiment
        from garage_exp.perception.detect import worker
        from garage_exp.search import launch

        # The render stage: each frame's lit picture, silhouettes, ground truth and sensor model, as the job's
        # pipeline asks for it (experiment.render_frames); the detect stage: sending a frame to the detector
        # process and waiting for its answer.
        real_frames = experiment.render_frames
        timers = self

        def render_frames(*args, **kwargs):
            frames = real_frames(*args, **kwargs)
            while True:
                t = time.perf_counter()
                try:
                    item = next(frames)
                except StopIteration:
                    return
                finally:
                    timers.render += time.perf_counter() - t
                yield item

        experiment.render_frames = render_frames
        for name in ("submit", "result"):
            self.wrap(worker.DetectorProcess, name, "detect")
        real_call = launch.CachedLaunch.__call__

        def call(self, batch, idx):
            start, r0, d0 = time.perf_counter(), timers.render, timers.detect
            try:
                return real_call(self, batch, idx)
            finally:
                timers.trials.append((start, time.perf_counter(), timers.render - r0, timers.detect - d0))

        launch.CachedLaunch.__call__ = call


def search(args: list[str], store: Path) -> None:
    from garage_exp.cli import app

    argv = ["-m", "hydra/sweeper=search", *SCENARIO, *SPACE, *args, f"search.storage=sqlite:///{store}/optuna.db",
            f"tracking.uri=sqlite:///{store}/mlflow.db", f"hydra.sweep.dir={store}/sweep-{time.time_ns()}",
            "hydra/job_logging=disabled", "hydra/hydra_logging=disabled"]
    try:
        app.cli(argv)
    except SystemExit as exc:
        if exc.code:
            raise


def hardest(store: Path, name: str) -> tuple[float, dict, int]:
    import optuna
    from optuna.trial import TrialState

    study = optuna.load_study(study_name=name, storage=f"sqlite:///{store}/optuna.db")
    best = max(study.get_trials(states=(TrialState.COMPLETE,)), key=lambda t: t.values[0])
    return best.values[0], best.params, len(study.trials)


def throughput(opts, store: Path, timers: Timers, lines: list[str]) -> None:
    search([f"search.trials={opts.trials}", "search.sampler=random", "search.study=throughput"], store)
    steady = timers.trials[1:]

    wall = steady[-1][1] - steady[0][0]  # ask/tell and the loop between trials included
    render = sum(t[2] for t in steady)
    detect = sum(t[3] for t in steady)
    other = wall - render - detect
    lines += ["## Throughput (5-frame trials, research plan, first trial left out)", "",
              "| trials | wall (s) | s / trial | trials / hour | rendering | detector wait | other (overhead) |",
              "|---|---|---|---|---|---|---|",
              f"| {len(steady)} | {wall:.1f} | {wall / len(steady):.2f} | {3600 * len(steady) / wall:.0f} | "
              f"{render / wall:.0%} | {detect / wall:.0%} | {other / wall:.0%} |", ""]
    print("\n".join(lines), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--trials", type=int, default=40)
    parser.add_argument("--levels", type=int, default=3)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--skip-grid", action="store_true")
    parser.add_argument("--skip-throughput", action="store_true")
    parser.add_argument("--out", default="search.md", help="file in benchmarks/results/ for the table")
    opts = parser.parse_args()
    os.environ.setdefault("YOLO_OFFLINE", "1")
    load = os.getloadavg()
    timers = Timers()
    timers.install()
    lines = [f"# studies/search.py, {time.strftime('%Y-%m-%d %H:%M')}, load average before {load[0]:.1f}",
             f"scenario: {' '.join(SCENARIO)}", f"space: {' '.join(SPACE)}", ""]
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp)
        if not opts.skip_throughput:
            throughput(opts, store, timers, lines)
        if not opts.skip_grid:
            grid_args = ["search.sampler=grid", f"search.grid_levels={opts.levels}", "search.study=grid"]
            search(grid_args, store)
            g_best, g_params, g_n = hardest(store, "grid")
            tpe = []
            for seed in range(opts.seeds):
                search([f"search.trials={g_n}", "search.sampler=tpe", f"search.study=tpe{seed}", f"search.seed={seed}"],
                       store)
                tpe.append(hardest(store, f"tpe{seed}"))
            fmt = lambda p: ", ".join(f"{k.split('.')[-1]}={v:.2f}" for k, v in p.items())  # noqa: E731
            lines += [f"## Search against grid, same budget ({g_n} trials of 5 frames each)", "",
                      "| sampler | trials | hardest fair difficulty | its values |", "|---|---|---|---|",
                      f"| grid ({opts.levels} levels a factor) | {g_n} | {g_best:.3f} | {fmt(g_params)} |"]
            lines += [f"| TPE, seed {k} | {n} | {best:.3f} | {fmt(params)} |" for k, (best, params, n) in enumerate(tpe)]
            wins = sum(best > g_best for best, _, _ in tpe)
            lines += ["", f"TPE harder than the grid's hardest cell in {wins} of {len(tpe)} seeds; TPE / grid: "
                      + ", ".join(f"{best / g_best:.2f}" for best, _, _ in tpe), ""]
    load = os.getloadavg()
    lines.append(f"load average after {load[0]:.1f}")
    text = "\n".join(lines)
    print(text)
    (RESULTS / opts.out).write_text(text + "\n")


if __name__ == "__main__":
    sys.exit(main())
