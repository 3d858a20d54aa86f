"""A cheap first look at a trial before it pays for the full render and three detectors (multi-fidelity, as
SAVME pre-screens with a cheap simulator).

`search.prescreen.level`:
- `truth`: the trial's frames at a fraction of the resolution (`scale`), ground truth only. A trial whose target
  is never fairly visible (for the late objective: never before the critical distance) is pruned as
  infeasible without its full render. The rule is looser than the full one (`slack_visible`), so a trial that
  might pass it pays full price.
- `detector`: also one detector (the first model, at `scale` of the input size) on those frames. A trial it
  finds clearly easy (difficulty under `easy`; or, late objective, confirmed `slack` metres before the critical
  distance) is pruned as screened easy. One small model on a small picture misses more than three on the full
  one, so it errs towards calling a trial hard, which costs only time.

Everything uncertain runs in full. Pruned trials tell Optuna nothing better than a complete one, so the
samplers learn to avoid those regions as they avoid infeasible ones.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pandas as pd
from omegaconf import DictConfig, open_dict

from garage_exp.core.errors import GarageError
from garage_exp.results.table import FairRule
from garage_exp.search.objectives import objective

LEVELS = ("none", "truth", "detector")


@dataclass
class Look:
    """What the cheap look decided: run the trial in full, or prune it (`why`: infeasible | easy)."""

    full: bool
    why: str = ""
    frames: int = 0
    attrs: dict = field(default_factory=dict)


def check_prescreen(conf) -> None:
    if conf.level not in LEVELS:
        raise GarageError(f"unknown level {conf.level!r} ({' | '.join(LEVELS)})", "search.prescreen.level")
    if not 0.1 <= float(conf.scale) <= 1.0:
        raise GarageError(f"{conf.scale}: a resolution scale is in 0.1-1", "search.prescreen.scale")
    if not 0.0 <= float(conf.easy) <= 1.0:
        raise GarageError(f"{conf.easy} is outside 0-1", "search.prescreen.easy")
    if float(conf.slack) < 0 or float(conf.slack_visible) < 0:
        raise GarageError("slacks are >= 0", "search.prescreen.slack")


def cheap_config(cfg: DictConfig, scale: float) -> DictConfig:
    """The trial's config at `scale` of each camera's resolution, saving no frame."""
    cheap = copy.deepcopy(cfg)
    with open_dict(cheap):
        rig = cheap.camera
        if rig.width is not None:
            rig.width, rig.height = _scaled(rig.width, scale), _scaled(rig.height, scale)
        for cam in rig.cameras:
            cam.width, cam.height = _scaled(cam.width, scale), _scaled(cam.height, scale)
        cheap.renderer.save_frames = "none"
        cheap.dataset = False
    return cheap


def _scaled(pixels, scale: float) -> int:
    return max(32, int(round(int(pixels) * scale / 2)) * 2)


def cheap_detector(detector, scale: float):
    """The first model of the trial's detectors (a built `Detector`, or the `detector` node) at `scale` of its
    input size, on the process's one warm detector (the jobs' detector child, core.state.STATE.detector: its
    models load once, in one process)."""
    from garage_exp.perception.detect import Detector, build_detector
    from garage_exp.perception.detect.worker import WarmDetector

    from garage_exp.core.plain import settings

    built = detector if isinstance(detector, Detector) else build_detector(settings(detector))
    return WarmDetector(built.cheap(scale))  # checked, as in the job


def prepare(cfg: DictConfig, scale: float):
    """The trial's cheap job (`cheap_config`) prepared: its scene and spec, its detector built but not loaded
    (the cheap look loads the first model alone, `cheap_detector`)."""
    from garage_exp.run.preflight import preflight

    return preflight(cheap_config(cfg, scale), check_space=False, load=False)


def frames_table(cfg: DictConfig, detector, scale: float, prepared=None) -> tuple[pd.DataFrame, object]:
    """The frames' table at `scale` of the resolution (ground truth; with `detector`, a `Detector` or a `WarmDetector`,
    its scores too) and the job's setup. `prepared`: the cheap job (`prepare`) when at hand, else prepared here.
    The job's pipeline does it: the renderer opened as a job opens it, and, with a detector that detects in a
    child (`submit`/`result`: a `WarmDetector`), the scored camera's frame k detected while frame k+1 renders."""
    from garage_exp.core.plugins import build
    from garage_exp.render.open import open_renderer
    from garage_exp.results.table import frame_row
    from garage_exp.run.pipeline import FramePipeline
    from garage_exp.scenario.assemble import HIDDEN

    prepared = prepared if prepared is not None else prepare(cfg, scale)
    spec = prepared.spec
    renderer = open_renderer(spec.renderer, HIDDEN)
    renderer.load(prepared.scene)
    sensor = build(spec.sensor, "a sensor model", "sensor._target_")
    pipeline = FramePipeline(spec.frames, prepared.scene, renderer, sensor, np.random.default_rng(spec.seed + 1),
                             detector, detector.scoring() if detector is not None else {}, spec.scoring)
    scored = spec.primary
    frames = (item for item in pipeline.frames(prepared.setup.shots) if item.camera == scored)
    names = detector.names if detector is not None else []
    rows = []
    try:
        for item, dets in detected(pipeline, frames, detector):
            score = UNSCORED if dets is None else pipeline.score(item, dets)
            rows.append(frame_row(item.shot, item.camera, item.target, score, names, replicated=spec.replicates > 1))
    finally:
        if hasattr(detector, "drain"):
            detector.drain()  # a failed look leaves no answer in the pipe for the next job
    return pd.DataFrame(rows), prepared.setup


UNSCORED = SimpleNamespace(per_model=[], composite=0.0, detected=False, false_positives=0)  # ground truth alone


def detected(pipeline, frames, detector):
    """Each scored frame with its detections: overlapped with the next render as the job's (`FramePipeline.detected`)
    when the detector works in a child, in this process frame by frame otherwise (a built `Detector`), None
    without one."""
    if detector is None:
        return ((item, None) for item in frames)
    if hasattr(detector, "submit"):
        return pipeline.detected(frames)
    return ((item, detector.detect([item.rgb], pipeline.intrinsics[item.camera])[0]) for item in frames)


def lenient(rule: FairRule, scale: float, slack_visible: float) -> FairRule:
    """The fairness rule loosened for the cheap look: a box at the small scale, a visible fraction short by
    `slack_visible` (the small silhouettes' edges round the other way)."""
    return FairRule(max(0.0, rule.min_visible - slack_visible), rule.min_box * scale * 0.8,
                    min(1.0, rule.max_truncation + slack_visible))


def look(cfg: DictConfig, prepared=None) -> Look:
    """The cheap look at one trial's composed config; `prepared`: its cheap job (`prepare`) when at hand."""
    from garage_exp.results.table import fair_mask

    conf = cfg.search.prescreen
    scale, detect = float(conf.scale), conf.level == "detector"
    prepared = prepared if prepared is not None else prepare(cfg, scale)
    spec = prepared.spec
    detector = cheap_detector(spec.detector if spec.detector is not None else cfg.detector, scale) if detect else None
    table, setup = frames_table(cfg, detector, scale, prepared)
    rule = lenient(spec.fair, scale, float(conf.slack_visible))
    fair = fair_mask(table, rule) if len(table) else pd.Series(dtype=bool)
    attrs = {"prescreen_frames": len(table)}
    why = objective(str(cfg.search.objective)).screen(table, fair, setup, cfg, detect, attrs)
    return Look(not why, why, len(table), attrs)
