"""Shared by the benchmarks: a job's pieces built as `run.frames.run_frames` builds them, without Hydra's run or MLflow,
plus the machine description and CPU-time helpers the tables print."""

from __future__ import annotations

import os
import platform
import statistics
import time
from dataclasses import dataclass

import numpy as np

from garage_exp.cli import app  # noqa: F401 - registers the config schema and the garage_root resolver
from garage_exp.core.paths import PROJECT_ROOT


def compose(overrides: list[str]):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(str(PROJECT_ROOT / "conf"), version_base="1.3"):
        return hydra_compose("config", overrides=app.quote_numeric_choices(overrides))


def open_job_renderer(cfg):
    """The job's render scene, opened as a job opens it (`render.open.open_renderer`: the configured backend, its
    batching and sub-scenes)."""
    from garage_exp.render.open import open_renderer
    from garage_exp.scenario.assemble import HIDDEN

    return open_renderer(cfg.renderer, HIDDEN)


@dataclass
class Job:
    cfg: object
    scene: object
    setup: object
    renderer: object  # the render scene (render/batch.py), opened by `open_job_renderer`
    sensor: object

    def frames(self, n: int | None = None):
        """The job's rendered frames (first n shots), as the experiment's render stage yields them."""
        return self.pipeline().frames(self.setup.shots if n is None else self.setup.shots[:n])

    def pipeline(self, detector=None, scoring: dict | None = None):
        """The job's frame pipeline (run.pipeline) with a fresh sensor stream, as `run.frames.run_frames` makes
        it; `detector` (submit/result) for `detected`."""
        from garage_exp.run.pipeline import FramePipeline

        return FramePipeline(self.cfg, self.scene, self.renderer, self.sensor,
                             np.random.default_rng(self.cfg.seed + 1), detector, scoring or {})


@dataclass
class Prepared:
    """A job's scene and set-up as its preflight builds them (nothing loaded into a renderer yet)."""

    cfg: object
    scene: object
    setup: object

    def load(self) -> Job:
        """The scene loaded into the process's renderer, its shaders compiled: a Job."""
        from garage_exp.core.plugins import build

        renderer = open_job_renderer(self.cfg)
        renderer.load(self.scene)
        job = Job(self.cfg, self.scene, self.setup, renderer, build(self.cfg.sensor, "a sensor model",
                                                                      "sensor._target_"))
        for _ in job.frames(1):
            pass
        return job


def prepared_job(overrides: list[str]) -> Prepared:
    """The job of these overrides checked and built by its preflight (a generated plan's own garage values handed
    on, as a real job's are), not loaded."""
    from garage_exp.run.preflight import preflight

    cfg = compose(overrides)
    prepared = preflight(cfg, check_space=False, load=False)
    return Prepared(cfg, prepared.scene, prepared.setup)


def build_job(overrides: list[str], edit=None) -> Job:
    """The job of these overrides, its scene loaded (after `edit(scene)`, when given) and its shaders compiled."""
    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.run.spec import scene_spec
    from garage_exp.scenario.assemble import build_scene
    from garage_exp.plan import classify, load_plan
    from garage_exp.run.preflight import resolve_plan_path
    from garage_exp.core.plugins import build

    cfg = compose(overrides)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    scene, setup = build_scene(scene_spec(cfg), classified, VehicleLibrary(), np.random.default_rng(cfg.seed))
    if edit is not None:
        edit(scene)
    renderer = open_job_renderer(cfg)
    renderer.load(scene)
    job = Job(cfg, scene, setup, renderer, build(cfg.sensor, "a sensor model", "sensor._target_"))
    for _ in job.frames(1):  # the first frame compiles the shaders: a start-up cost, not a per-frame one
        pass
    return job


def cpu_seconds(pids: list[int] | None = None) -> float:
    """User + system CPU time of this process, or of the given processes (psutil), so far."""
    if not pids:
        t = os.times()
        return t.user + t.system
    import psutil

    return sum(sum(psutil.Process(p).cpu_times()[:2]) for p in pids)


def timed(fn, pids: list[int] | None = None) -> tuple[float, float]:
    """Wall-clock seconds of fn() and the cores it kept busy on average (CPU seconds / wall seconds)."""
    c0, t0 = cpu_seconds(pids), time.perf_counter()
    fn()
    wall = time.perf_counter() - t0
    return wall, (cpu_seconds(pids) - c0) / wall


def median(values: list[float]) -> float:
    return statistics.median(values)


def machine() -> str:
    model = platform.processor() or "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores, {model}, {platform.system()} {platform.release()}"


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min) {five:.2f} (5 min)"
