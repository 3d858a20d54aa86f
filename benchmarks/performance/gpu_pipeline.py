"""The batched GPU pipeline against SAPIEN's own ceiling, in one run, on one card (issue 34). One command:

    python -m benchmarks.performance.gpu_pipeline --out gpu_pipeline.json

On a machine without CUDA it refuses in one line (exit 2). It measures, in this process, on the project's real
garage (the research plan, case 1, 640x480 unless --width/--height):
- ceiling: the render scene's CUDA branch (`render.open.open_renderer` with `renderer.device=cuda`, N
  sub-scenes in one RenderSystemGroup): poses from the CUDA tensor, one group picture, Color and Segmentation
  read as CUDA tensors; no project work. frames/s for each N of --scenes.
- pipeline: the frame pipeline over that scene (`run.pipeline.FramePipeline.shots`: `render_batch`, the
  silhouettes, ground truth and the camera model (--sensor) on the tensors, perception/groundtruth.py and
  sensor.py, each frame then copied to numpy for the detector). frames/s, and its ratio to the ceiling.
- agreement: the CPU path's `SapienRenderer` (on the same card, a scene of one sub-scene) and the CUDA branch on
  the same shots: colour max / mean absolute difference (8-bit levels) and ground truth compared record by
  record (the goal: equal to the pixel).
- detectors: end to end, the pipeline's frames through the project's composite detector (`Detector.detect` on a
  batch: the entries of detector.models, e.g. `--detector official_pt` for .pt networks that run on the card),
  frames/s.
- fisheye4: the four-fisheye rig's faces rendered batched and remapped with grid_sample, delivered Mpx/s.
- search: trials/hour of today's search on this card (benchmarks/studies/search.py's throughput run, --trials).
- gym: StepOut-v0 env steps/s (random actions), alone and as a vector env of 4 and 16 episodes.
Each section records its error instead of its numbers when it fails, so one run gives every figure it can.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import traceback
from pathlib import Path

from benchmarks.common import ROOT

SCENE = ["plan=research", "case=1", "palette.target_colours=[black]", "renderer.device=cuda", "look=flat"]


def timed_rate(step, frames_per_step: int, seconds: float) -> float:
    """frames/s of `step` (called until `seconds` have passed, after two warm-up calls), CUDA synchronised."""
    import torch

    for _ in range(2):
        step()
    torch.cuda.synchronize()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        step()
        n += 1
    torch.cuda.synchronize()
    return n * frames_per_step / (time.perf_counter() - t0)


def batch_of(shots, n):
    return [shots[i % len(shots)] for i in range(n)]


class Batched:
    """The frame pipeline over one job's scene in a render scene of `scenes` sub-scenes on the GPU."""

    def __init__(self, job, scenes: int):
        import numpy as np

        from garage_exp.render.open import open_renderer
        from garage_exp.run.pipeline import FramePipeline, in_view
        from garage_exp.scenario.assemble import HIDDEN

        self.job = job
        self.stage = open_renderer(job.cfg.renderer, HIDDEN, scenes)
        self.stage.load(job.scene)
        self.pipeline = FramePipeline(job.cfg, job.scene, self.stage, job.sensor, np.random.default_rng(1))
        self.names = in_view(job.scene, {})
        self.camera = job.scene.cameras[0].name

    def render(self, shots):
        """The render scene's one call: each shot's Take (frame and silhouettes as CUDA tensors)."""
        return self.stage.render_batch(shots, [self.camera], [self.names] * len(shots))

    def ceiling(self):
        """SAPIEN alone: the group's poses applied from the CUDA tensor, one picture, Color and Segmentation read
        as CUDA tensors (the tensor was filled once; the lights stay where the last `render` put them)."""
        import torch

        gpu = self.stage.gpu
        gpu.group.update_render()
        lit = gpu.lit[self.camera]
        lit.take_picture()
        return (torch.as_tensor(lit.get_picture_cuda("Color"), device="cuda"),
                torch.as_tensor(lit.get_picture_cuda("Segmentation"), device="cuda"))

    def frames(self, shots, rng):
        """The pipeline's frames (`run.pipeline.Rendered`) of the shots, each drawing from `rng`."""
        n = len(shots)
        return list(self.pipeline.shots(shots, [self.camera], [self.names] * n, [rng] * n))


def section(results: dict, name: str, fn) -> None:
    t0 = time.perf_counter()
    try:
        results[name] = fn()
    except Exception as exc:  # a benchmark section that fails says why; the others still run
        results[name] = {"error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc()[-2000:]}
    print(f"{name}: {json.dumps(results[name])[:400]} ({time.perf_counter() - t0:.0f} s)", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="gpu_pipeline.json")
    parser.add_argument("--scenes", default="16,64,256")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--sensor", default="noisy")
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--detector", default="coco3", help="the detector group's level (official_pt: .pt files)")
    parser.add_argument("--skip", default="", help="comma-separated sections to leave out")
    opts = parser.parse_args()
    os.environ.setdefault("YOLO_OFFLINE", "1")
    from garage_exp.core.errors import GarageError
    from garage_exp.render.sapien_batch import require_cuda

    try:
        require_cuda()
    except GarageError as exc:
        print(f"gpu_pipeline: {exc}", file=sys.stderr)
        return 2
    import numpy as np
    import torch

    from benchmarks.jobkit import build_job

    skip = set(filter(None, opts.skip.split(",")))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    results: dict = {"card": torch.cuda.get_device_name(), "commit": commit, "date": time.strftime("%Y-%m-%d %H:%M"),
                     "command": " ".join(sys.argv), "size": f"{opts.width}x{opts.height}"}
    size = [f"camera.width={opts.width}", f"camera.height={opts.height}", f"sensor={opts.sensor}"]
    job = build_job([*SCENE, *size, f"detector={opts.detector}"])
    shots = job.setup.shots

    def ceiling_and_pipeline():
        out = {}
        for n in [int(x) for x in opts.scenes.split(",")]:
            b = Batched(job, n)
            batch = batch_of(shots, n)
            b.render(batch)  # poses the batch once: the ceiling then re-renders it
            ceiling = timed_rate(b.ceiling, n, opts.seconds)
            g = torch.Generator(device="cuda").manual_seed(1)
            pipeline = timed_rate(lambda: b.frames(batch, g), n, opts.seconds)
            out[str(n)] = {"ceiling_fps": round(ceiling, 1), "pipeline_fps": round(pipeline, 1),
                           "ratio": round(pipeline / ceiling, 3)}
            del b
        return out

    def agreement():
        from garage_exp.perception.groundtruth import mask_stats
        from omegaconf import OmegaConf

        from garage_exp.render.open import open_renderer
        from garage_exp.scenario.assemble import HIDDEN

        n = min(16, len(shots))
        b = Batched(job, n)
        batch = batch_of(shots, n)
        cpu = open_renderer(OmegaConf.merge(job.cfg.renderer, {"device": "auto"}), HIDDEN, 1)  # the CPU path
        cpu.load(job.scene)
        diffs, equal = [], 0
        for k, take in enumerate(b.render(batch)):
            (want,) = cpu.render_batch([batch[k]], [b.camera], [b.names])
            got = mask_stats(take.frame, take.silhouettes, take.ids)
            ref = mask_stats(want.frame, want.silhouettes, want.ids)
            equal += [s for s in got if s.full_box is not None] == [s for s in ref if s.full_box is not None]
            diffs.append(np.abs(want.frame.rgb.astype(int) - take.frame.rgb.cpu().numpy().astype(int)))
        d = np.stack(diffs)
        return {"frames": n, "colour_max_levels": int(d.max()), "colour_mean_levels": round(float(d.mean()), 4),
                "colour_share_over_2_levels": round(float((d > 2).mean()), 6), "truth_equal_frames": int(equal)}

    def detectors():
        from garage_exp.perception.detect import build_detector

        detector = build_detector(job.cfg.detector)
        detector.check()
        out = {"models": list(detector.names)}
        for n in (16, 64):
            b = Batched(job, n)
            batch = batch_of(shots, n)
            rng = np.random.default_rng(1)

            def step():
                detector.detect([item.rgb for item in b.frames(batch, rng)], None)
            out[f"batch{n}_fps"] = round(timed_rate(step, n, opts.seconds), 1)
        out["on_card"] = [e.name for e in detector.entries if e.takes_tensors()]
        return out

    def fisheye4():
        from garage_exp.render.fisheye import cube_map
        from garage_exp.scene.lenses import lens_of

        rig = build_job([*SCENE, "camera=fisheye4", f"sensor={opts.sensor}"])
        specs = [c for c in rig.scene.cameras if c.fisheye]
        cube = cube_map(lens_of(specs[0]))
        h, w = cube.atlas_shape
        atlas = torch.zeros((4 * len(cube.faces), h, w, 3), dtype=torch.uint8, device="cuda")
        cube.remap_colour(atlas)  # its grid_sample grid, made once per device
        remap = timed_rate(lambda: cube.remap_colour(atlas), 4 * len(cube.faces), opts.seconds)
        # The faces themselves are pinhole crops: their render rate is the ceiling section's at their size.
        px = specs[0].width * specs[0].height
        return {"cameras": len(specs), "size": f"{specs[0].width}x{specs[0].height}",
                "face_pixels_per_fisheye": cube.rendered_pixels,
                "remap_pictures_per_s": round(remap, 1), "remap_mpx_per_s": round(remap * px / 1e6, 1),
                "note": "render of the faces not batched yet: delivered Mpx/s = min(remap, face render rate)"}

    def search():
        # The search study's throughput run in its own process (the benchmark groups do not import one another);
        # its table's row: | trials | wall (s) | s / trial | trials / hour | ...
        done = subprocess.run([sys.executable, "-m", "benchmarks.studies.search", "--skip-grid",
                               f"--trials={opts.trials}", "--out=search_gpu.md"], cwd=ROOT, capture_output=True,
                              text=True, check=True)
        rows = [line.split("|")[1:-1] for line in done.stdout.splitlines() if line.startswith("| ")]
        row = next(r for r in rows if r[0].strip().isdigit())
        return {"trials": int(row[0]), "trials_per_hour": int(row[3]),
                "note": "the search on this card, one trial after another (a batch's trials are not yet rendered together)"}

    def gym():
        from garage_exp.gym.env import StepOutEnv, compose

        env = StepOutEnv(compose(["renderer.device=cuda"]))
        env.reset(seed=0)
        steps, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < opts.seconds:
            _, _, done, _, _ = env.step(env.action_space.sample())
            steps += 1
            if done:
                env.reset()
        out = {"steps_per_s": round(steps / (time.perf_counter() - t0), 1)}
        from garage_exp.gym.vector import StepOutVectorEnv

        for k in (4, 16):  # K episodes' frames a vector step: one batch through the pipeline
            venv = StepOutVectorEnv(k, compose(["renderer.device=cuda"]))
            venv.reset(seed=0)
            venv.step(venv.action_space.sample())
            before, t0 = venv.renders, time.perf_counter()
            while time.perf_counter() - t0 < opts.seconds:
                venv.step(venv.action_space.sample())
            out[f"vector{k}_steps_per_s"] = round((venv.renders - before) / (time.perf_counter() - t0), 1)
            venv.close()
        return out

    for name, fn in (("batched", ceiling_and_pipeline), ("agreement", agreement), ("detectors", detectors),
                     ("fisheye4", fisheye4), ("search", search), ("gym", gym)):
        if name not in skip:
            section(results, name, fn)
    Path(opts.out).write_text(json.dumps(results, indent=1))
    print(f"wrote {opts.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
