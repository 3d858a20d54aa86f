"""One job's frames: run every shot through the frame pipeline (`run.pipeline`: render, ground truth, camera
model, detect, score), write the frame table, log.

Detection overlaps rendering: this process renders (SAPIEN) while a child process detects the previous frame
(garage_exp/perception/detect/worker.py). Results come back in frame order, so the table is the serial loop's;
docs/performance.md has the measured gain.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from garage_exp import exports
from garage_exp.results import figures, late
from garage_exp.results import table as frame_table
from garage_exp.results.summary import JobSummary
from garage_exp.run.pipeline import FramePipeline
from garage_exp.scenario import CaseSetup
from garage_exp.slots.frames import SlotFrames, slot_line
from garage_exp.slots.frames import wanted as slot_frames_wanted
from garage_exp.run.spec import JobSpec
from garage_exp.scenario.fits import hint

log = logging.getLogger("garage_exp")
def late_verdict(spec: JobSpec, table: pd.DataFrame, setup: CaseSetup, out: Path, run) -> dict:
    """Each trajectory's late verdict (late.csv, logged) and the job's late metrics."""
    per = late.trajectories(table, {s.index: s.time for s in setup.shots}, frame_table.fair_mask(table, spec.fair),
                            spec.ego, spec.scoring.threshold)
    per.to_csv(out / "late.csv", index=False)
    run.log_artifact(out / "late.csv")
    return late.summary(per, spec.ego)


def run_frames(prepared, out: Path, run) -> JobSummary:
    """Render and score the frames of the scene the job's preflight built (`run.preflight.PreparedJob`, its
    `spec` saying how), log them on the job's run, and return the summary (`difficulty`, and `fair_*`: the
    search's objective). The stages are handed the spec's typed parts, never the config."""
    from garage_exp.core.plugins import build
    from garage_exp.render.open import open_renderer
    from garage_exp.scenario.assemble import HIDDEN
    from garage_exp.scene.gltf import export_glb

    scene, setup, spec = prepared.scene, prepared.setup, prepared.spec
    # The detector the preflight opened and checked (its models loaded in the detector's process): not again.
    detector = prepared.open_detector()
    classes = spec.detector.scoring()
    sensor = build(spec.sensor, "a sensor model", "sensor._target_")
    renderer = open_renderer(spec.renderer, HIDDEN)  # renderer.scenes sub-scenes, batched by the backend
    renderer.load(scene)
    trial = spec.outputs.lean  # a search trial: lean (the study's parent holds map, plots, frames)
    if not trial:
        run.log_artifact(export_glb(scene, out / "scene.glb"))

    frames_dir = out / "frames"
    frames_dir.mkdir(exist_ok=True)
    dataset = exports.DatasetExports(out / "dataset") if spec.outputs.dataset else None
    sensor_rng = np.random.default_rng(spec.seed + 1)
    rows, keep = [], {}
    # Tables of scenes with people say each target's kind; vehicle-only tables stay as they were.
    kinds = {e.name: e.kind or "vehicle" for e in scene.actors()} if scene.people() else {}
    table_path = out / "frames.csv"
    fisheye = any(cam.fisheye for cam in scene.cameras)
    slots = (SlotFrames.open(spec.scene, spec.slot_detector, spec.outputs.save_frames != "none", prepared, out)
             if slot_frames_wanted(spec.scene) else None)
    pipeline = FramePipeline(spec.frames, scene, renderer, sensor, sensor_rng, detector, classes, spec.scoring)
    one_run = trial and run.run_id is None  # a one-shot search's trial (search.runs=per_search): no bar a trial
    frames = pipeline.frames(setup.shots, progress=None if one_run else f"case {spec.names.case}")
    try:
        for item, dets in pipeline.detected(frames):
            shot, target = item.shot, item.target
            score = pipeline.score(item, dets)
            row = frame_table.frame_row(shot, item.camera, target, score, detector.names, kinds.get(shot.target),
                                    replicated=spec.replicates > 1, off_axis=fisheye)
            rows.append(row)
            if dataset is not None:
                dataset.add(f"{shot.index:04d}_{item.camera}", item.camera, item.rgb, item.truth, scene,
                            item.geometry)
            keep[(shot.index, item.camera)] = (item.rgb, target, dets)
            if slots is not None:
                slots.add(shot, item.camera, item.rgb)
            if spec.outputs.save_frames == "all":
                figures.save_frame(frames_dir / f"{shot.index:04d}_{item.camera}.png", item.rgb, target, dets,
                                   score)
            if len(keep) > 3 * len(scene.cameras) and not trial:  # a trial keeps all: its hardest fair one is saved
                keep = figures.prune_key_frames(keep, rows)
    except KeyboardInterrupt:
        detector.abandon()  # do not make Ctrl-C wait for a frame's detection or the models' loading
        raise
    finally:
        frames.close()
        detector.drain()  # a failed job leaves no answer in the pipe for the next one
        table = pd.DataFrame(rows)
        table.to_csv(table_path, index=False)
        run.log_artifact(table_path)  # kept even when the job fails half-way
    primary, threshold = spec.primary, spec.scoring.threshold  # the case's camera, else the first
    metrics = frame_table.summarise(table, threshold, primary=primary)
    run.log_series("confidence", table[table.camera == primary].composite.tolist())
    run.log_series("visible_fraction", table[table.camera == primary].visible_fraction.tolist())
    metrics.update(frame_table.fair_summary(table, primary, spec.fair, threshold))
    if spec.moving:  # seen in time to stop? (a static ego has no stopping distance)
        metrics.update(late_verdict(spec, table[table.camera == primary], setup, out, run))
    if slots is not None:
        metrics.update(slots.finish(run))
        print(slot_line(metrics))
    summary = JobSummary.of(metrics)
    run.log_metrics(summary.as_dict())
    if len(scene.cameras) > 1:  # which camera saw the target first and best (frame_table.per_camera)
        cams = frame_table.per_camera(table, threshold)
        cams.to_csv(out / "cameras.csv", index=False)
        run.log_artifact(out / "cameras.csv")
        print(f"cameras: {frame_table.camera_line(cams)}")
    if trial:
        frame = figures.save_hardest_fair(keep, table, frames_dir, primary, spec.fair)
        if frame is not None:
            run.log_artifact(frame, "frames")
            summary = summary.with_(frame=str(frame))
    else:
        run.log_artifact(figures.plot_confidence(table, out / "confidence.png", setup.position_label, threshold,
                                                 figures.title(spec.names)))
        if spec.outputs.save_frames != "none":
            for path in figures.save_key_frames(keep, table, frames_dir):
                run.log_artifact(path, "frames")
    if dataset is not None:
        run.log_artifact(dataset.finish())
    print(frame_table.one_line(spec.names, summary, [cam.name for cam in scene.cameras], primary))
    if not summary.fair_frames and not trial:
        print(no_fair_line(spec, len(scene.cameras) > 1))
    if summary.late_testable is not None:
        print(late.line(summary.as_dict()))
    return summary


def no_fair_line(spec: JobSpec, rig: bool) -> str:
    """Said when no frame tested the detector fairly: its numbers measure a hidden, tiny or cut-off target."""
    where = hint(spec.names.case, spec.names.plan, spec.plan_file)
    rule = spec.fair
    return (f"garage_exp: no frame {f'of the primary camera ({spec.primary}) ' if rig else ''}is a fair test (the "
            f"target at least {rule.min_visible:g} visible, {rule.min_box:g} px tall, at most "
            f"{rule.max_truncation:g} cut off): the numbers above measure no fair frame"
            + (f"; {where}" if where else ""))
