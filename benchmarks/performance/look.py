"""Frame cost of the real look against the flat one: `python -m benchmarks.performance.look [--frames 24] [--repeat 3]`.

A frame is what the job pays per camera image before detection: the lit render, ground truth's silhouette
renders and the sensor model (`run.frames.render_frames`). Each plan and look is one job built as the real
one is (jobkit), warmed by one frame; the time is the best of `--repeat` passes over `--frames` shots, the looks
alternating, so the ratio is measured in one run, in one process, on one machine. Issue 21's goal: real <= 1.5x
flat.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("TQDM_DISABLE", "1")  # the table, not 30 progress bars

from benchmarks import jobkit

PLANS = {"research": ["case=light"], "garage26x30": ["plan=garage26x30", "case=1", "case.motion.step=2"]}


def frame_seconds(overrides: list[str], frames: int, repeat: int) -> tuple[float, float]:
    """Best seconds a frame (flat, real): the two looks alternate, each reloaded before its pass, so a load
    spike hits both alike."""
    best = {"flat": float("inf"), "real": float("inf")}
    for _ in range(repeat):
        for look in best:
            job = jobkit.build_job([*overrides, f"look={look}"])  # loads the scene, warms it by one frame
            start = time.perf_counter()
            n = sum(1 for _ in job.frames(frames))
            best[look] = min(best[look], (time.perf_counter() - start) / n)
    return best["flat"], best["real"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    print(f"# {jobkit.machine()}; before: {jobkit.load()}")
    print("| plan | flat s/frame | real s/frame | real/flat |")
    print("|---|---|---|---|")
    for plan, overrides in PLANS.items():
        flat, real = frame_seconds(overrides, args.frames, args.repeat)
        print(f"| {plan} | {flat:.3f} | {real:.3f} | {real / flat:.2f}x |", flush=True)
    print(f"# after: {jobkit.load()}")


if __name__ == "__main__":
    main()
