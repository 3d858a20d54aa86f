"""Per-frame cost of each camera rig against the single front camera, as ratios measured in one run:
`python -m benchmarks.performance.rigs [--shots 6] [--rounds 3] [--case 1]`.

A frame here is one shot of the case: every camera of the rig rendered, with its ground truth (the unoccluded
silhouettes) and the sensor model, as the job's render stage does it (`run.pipeline.FramePipeline.frames`); detection is
left out (it costs the same per image for every rig: 40-55 ms per model, docs/performance.md). The rigs take
turns round by round (a scene load between turns, not timed), so a load that changes during the run falls on
all rigs alike; ratios are of the median over rounds. Each rig's first frame compiles nothing new after the
first rig (one renderer per process), but its new cameras are warmed with one untimed shot.

Fisheye rigs render the cube faces their lenses see (render/fisheye.py): the table also gives the pixels
rendered per shot, faces included, against the pixels of the images the rig delivers.
"""

from __future__ import annotations

import argparse
import time

from benchmarks import jobkit

RIGS = {
    "front": [],
    "front, mount=bumper fovy=120": ["camera.mount=bumper", "camera.fovy=120"],
    "surround (4 pinhole)": ["camera=surround"],
    "fisheye (1 fisheye)": ["camera=fisheye"],
    "fisheye, view=perspective": ["camera=fisheye", "camera.view=perspective"],
    "fisheye4 (4 fisheye)": ["camera=fisheye4"],
}


def rendered_pixels(job) -> tuple[int, int]:
    """Pixels rendered per shot (the cube faces of fisheye cameras) and pixels of the delivered images."""
    from garage_exp.render.fisheye import cube_map
    from garage_exp.scene.lenses import lens_of

    rendered = delivered = 0
    for spec in job.scene.cameras:
        delivered += spec.width * spec.height
        rendered += cube_map(lens_of(spec)).rendered_pixels if spec.fisheye else spec.width * spec.height
    return rendered, delivered


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shots", type=int, default=6, help="shots timed per rig and round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--case", default="1")
    args = parser.parse_args()
    common = [f"case={args.case}", "renderer.save_frames=none", "palette.target_colours=[black]"]
    jobs = {}
    for name, overrides in RIGS.items():  # build each scene once (and warm its cameras)
        jobs[name] = jobkit.build_job([*common, *overrides])
    print(f"# {jobkit.machine()}; {jobkit.load()}")
    times: dict[str, list[float]] = {name: [] for name in RIGS}
    for _ in range(args.rounds):
        for name, job in jobs.items():
            job.renderer.load(job.scene)
            for _ in job.frames(1):  # new cameras: the first picture sets up their buffers
                pass
            t = time.perf_counter()
            for _ in job.frames(args.shots):
                pass
            times[name].append((time.perf_counter() - t) / args.shots)
    base = jobkit.median(times["front"])
    print(f"case {args.case}, {args.shots} shots x {args.rounds} rounds per rig; render + ground truth + sensor, "
          "no detection")
    print(f"{'rig':<32} {'cameras':>7} {'s/shot':>7} {'ratio':>6} {'Mpx rendered':>12} {'Mpx delivered':>13}")
    for name, job in jobs.items():
        t = jobkit.median(times[name])
        rendered, delivered = rendered_pixels(job)
        print(f"{name:<32} {len(job.scene.cameras):>7} {t:>7.3f} {t / base:>6.2f} {rendered / 1e6:>12.2f} "
              f"{delivered / 1e6:>13.2f}")
    print(f"# {jobkit.load()}")


if __name__ == "__main__":
    main()
