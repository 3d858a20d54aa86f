"""One job's frames: render every shot, score the target with the detectors, write the frame table, log.

The frame loop is a two-stage pipeline: this process renders (SAPIEN) while a child process detects the
previous frame (garage_exp/perception/detect/worker.py). Results come back in frame order, so the table is the
serial loop's; docs/performance.md has the measured gain.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig

from garage_exp import exports
from garage_exp.perception.groundtruth import VehicleTruth
from garage_exp.render.composite import blank_composite
from garage_exp.results import figures, late
from garage_exp.results import table as frame_table
from garage_exp.scenario import CaseSetup, Shot
from garage_exp.scenario.assemble import HIDDEN
from garage_exp.scenario.build import moves_ego
from garage_exp.scenario.fits import hint
from garage_exp.run.slots import SlotFrames, slot_line
from garage_exp.run.slots import wanted as slot_frames_wanted
from garage_exp.scene.camera import scored_camera
from garage_exp.scene.description import Scene

log = logging.getLogger("garage_exp")
@dataclass
class Rendered:
    """One camera's frame as the detectors see it (after the sensor model), with its ground truth."""

    shot: Shot
    camera: str
    rgb: np.ndarray
    truth: list[VehicleTruth]
    target: VehicleTruth | None
    geometry: exports.FrameGeometry | None  # the camera and the actors' poses, for the dataset's 3D labels


def replicate_materials(cfg: DictConfig, scene: Scene, replicate: int, loaded: int) -> dict:
    """Old -> new materials that turn the loaded replicate's surfaces into `replicate`'s: each replicate draws
    its own stains, cracks and (materials=random) its own grime, wetness and tint: domain randomisation within a
    job, the same draw in every cell of a sweep."""
    from garage_exp.scenario.assemble import marking_wear
    from garage_exp.scene.look import dress_for, redress

    if str(cfg.materials.level) == "none":
        return {}

    def draw(k):
        return dress_for(cfg.materials, int(cfg.seed) + k, marking_wear(cfg))

    back = redress(scene, draw(loaded))  # the scene holds replicate 0's materials; the renderer `loaded`'s
    return {back[m]: new for m, new in redress(scene, draw(replicate)).items()}


def render_frames(cfg: DictConfig, scene: Scene, setup: CaseSetup, renderer, sensor,
                  sensor_rng: np.random.Generator) -> Iterator[Rendered]:
    """Every camera of every shot, in order: the sensor's random stream is drawn in this order."""
    from tqdm import tqdm

    from garage_exp.perception.groundtruth import ground_truth

    dressed = None  # the replicate whose materials are loaded (the build drew replicate 0's)
    for shot in tqdm(setup.shots, desc=f"case {cfg.case.name}", unit="frame", leave=False):
        if shot.replicate != (dressed or 0) and hasattr(renderer, "restyle"):
            renderer.restyle(replicate_materials(cfg, scene, shot.replicate, dressed or 0))
            dressed = shot.replicate
        renderer.set_pose("ego", shot.ego)
        for name, pose in shot.poses.items():
            renderer.set_pose(name, pose if pose is not None else HIDDEN)
        for cam in scene.cameras:
            frame = renderer.render(cam.name)
            in_view = [v.name for v in scene.actors()
                       if v.role != "ego" and v.kind != "box" and shot.poses.get(v.name, v.pose)]
            silhouettes = renderer.unoccluded_ids(cam.name, in_view)
            truth = ground_truth(frame, silhouettes, scene, renderer.ids)
            if not scene.background and str(cfg.look.name) != "flat":
                # The blank control is a scene (the car alone on grey) that the camera then sees: exposure, blur
                # and noise act on the grey too. The flat look keeps the order its published tables used.
                rgb = sensor.apply(blank_composite(frame.rgb, frame, renderer.ids, [shot.target]), sensor_rng)
            else:
                rgb = sensor.apply(frame.rgb, sensor_rng)
                if not scene.background:
                    rgb = blank_composite(rgb, frame, renderer.ids, [shot.target])
            target = next((t for t in truth if t.name == shot.target), None)
            # copied only when a dataset will label the frame in 3D
            geometry = exports.FrameGeometry.of(frame) if cfg.dataset else None
            yield Rendered(shot, cam.name, rgb, truth, target, geometry)


def late_verdict(cfg: DictConfig, table: pd.DataFrame, setup: CaseSetup, out: Path, run) -> dict:
    """Each trajectory's late verdict (late.csv, logged) and the job's late metrics."""
    per = late.trajectories(table, {s.index: s.time for s in setup.shots}, frame_table.fair_mask(table, cfg.search),
                            cfg.ego, cfg.detector.threshold)
    per.to_csv(out / "late.csv", index=False)
    run.log_artifact(out / "late.csv")
    return late.summary(per, cfg.ego)


def overlapped(frames: Iterable[Rendered], detector, cameras: dict) -> Iterator[tuple[Rendered, list]]:
    """Each frame with its detections, in order. Frame k is submitted (with its camera's intrinsics, `cameras`
    by name) before frame k+1 is rendered, so the detector (a child process) works on k while this process
    renders k+1."""
    waiting: deque[Rendered] = deque()
    rendered = iter(frames)
    while True:
        try:
            frame = next(rendered)
        except StopIteration:
            break
        except Exception as exc:
            # Rendering failed: the frame already sent still gets its row, as the serial loop would have kept it.
            while waiting:
                yield waiting.popleft(), detector.result()
            raise exc
        detector.submit(frame.rgb, cameras.get(frame.camera))
        waiting.append(frame)
        if len(waiting) > 1:
            yield waiting.popleft(), detector.result()
    while waiting:
        yield waiting.popleft(), detector.result()


def run_frames(cfg: DictConfig, prepared, out: Path, run) -> dict:
    """Render and score the frames of the scene the job's preflight built (`run.preflight.PreparedJob`), log
    them on the job's run, and return the summary metrics (`difficulty`, and `fair_*`: the search's
    objective)."""
    from garage_exp.core.plugins import build
    from garage_exp.perception.detect import Intrinsics, score_target
    from garage_exp.perception.detect.worker import open_detector
    from garage_exp.render import open_renderer
    from garage_exp.scene.gltf import export_glb

    scene, setup = prepared.scene, prepared.setup
    cameras = {cam.name: Intrinsics.of(cam) for cam in scene.cameras}
    # The detector the preflight checked (its models loaded in the detector's process): not checked again.
    detector = open_detector(prepared.detector, cameras[scene.cameras[0].name])
    classes = prepared.detector.scoring()
    sensor = build(cfg.sensor, "a sensor model", "sensor._target_")
    renderer = open_renderer(cfg.renderer)
    renderer.load(scene)
    trial = cfg.search.trial is not None  # a search trial: lean (the study's parent holds map, plots, frames)
    if not trial:
        run.log_artifact(export_glb(scene, out / "scene.glb"))

    frames_dir = out / "frames"
    frames_dir.mkdir(exist_ok=True)
    dataset = exports.DatasetExports(out / "dataset") if cfg.dataset else None
    sensor_rng = np.random.default_rng(cfg.seed + 1)
    rows, keep = [], {}
    # Tables of scenes with people say each target's kind; vehicle-only tables stay as they were.
    kinds = {e.name: e.kind or "vehicle" for e in scene.actors()} if scene.people() else {}
    table_path = out / "frames.csv"
    fisheye = any(cam.fisheye for cam in scene.cameras)
    slots = SlotFrames.open(cfg, prepared, out) if slot_frames_wanted(cfg) else None
    frames = render_frames(cfg, scene, setup, renderer, sensor, sensor_rng)
    try:
        for item, dets in overlapped(frames, detector, cameras):
            shot, target = item.shot, item.target
            score = score_target(dets, target, item.truth, iou_threshold=cfg.detector.iou, match=cfg.detector.match,
                                 threshold=cfg.detector.threshold, **classes)
            row = frame_table.frame_row(shot, item.camera, target, score, detector.names, kinds.get(shot.target),
                                    replicated=cfg.replicates > 1, off_axis=fisheye)
            rows.append(row)
            if dataset is not None:
                dataset.add(f"{shot.index:04d}_{item.camera}", item.camera, item.rgb, item.truth, scene,
                            item.geometry)
            keep[(shot.index, item.camera)] = (item.rgb, target, dets)
            if slots is not None:
                slots.add(shot, item.camera, item.rgb)
            if cfg.renderer.save_frames == "all":
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
    primary = scored_camera(cfg.camera, str(cfg.case.get("camera") or ""))  # the case's camera, else the first
    summary = frame_table.summarise(table, cfg.detector.threshold, primary=primary)
    run.log_series("confidence", table[table.camera == primary].composite.tolist())
    run.log_series("visible_fraction", table[table.camera == primary].visible_fraction.tolist())
    search = cfg.search
    summary.update(frame_table.fair_summary(table, primary, search, cfg.detector.threshold))
    if moves_ego(cfg.case):  # seen in time to stop? (a static ego has no stopping distance)
        summary.update(late_verdict(cfg, table[table.camera == primary], setup, out, run))
    if slots is not None:
        summary.update(slots.finish(run))
        print(slot_line(summary))
    run.log_metrics(summary)
    if len(scene.cameras) > 1:  # which camera saw the target first and best (frame_table.per_camera)
        cams = frame_table.per_camera(table, cfg.detector.threshold)
        cams.to_csv(out / "cameras.csv", index=False)
        run.log_artifact(out / "cameras.csv")
        print(f"cameras: {frame_table.camera_line(cams)}")
    if trial:
        summary["frame"] = figures.save_hardest_fair(keep, table, frames_dir, primary, search)
        if summary["frame"] is not None:
            run.log_artifact(summary["frame"], "frames")
    else:
        run.log_artifact(figures.plot_confidence(table, out / "confidence.png", setup.position_label, cfg))
        if cfg.renderer.save_frames != "none":
            for path in figures.save_key_frames(keep, table, frames_dir):
                run.log_artifact(path, "frames")
    if dataset is not None:
        run.log_artifact(dataset.finish())
    print(frame_table.one_line(cfg, summary, [cam.name for cam in scene.cameras], primary))
    if not summary["fair_frames"] and not trial:
        print(no_fair_line(cfg, primary, len(scene.cameras) > 1))
    if "late_testable" in summary:
        print(late.line(summary))
    return summary


def no_fair_line(cfg: DictConfig, primary: str, rig: bool) -> str:
    """Said when no frame tested the detector fairly: its numbers measure a hidden, tiny or cut-off target."""
    where = hint(cfg.case.name, cfg.plan.name, cfg.plan.file)
    return (f"garage_exp: no frame {f'of the primary camera ({primary}) ' if rig else ''}is a fair test (the target "
            f"at least {cfg.search.min_visible:g} visible, {cfg.search.min_box:g} px tall, at most "
            f"{cfg.search.max_truncation:g} cut off): the numbers above measure no fair frame"
            + (f"; {where}" if where else ""))
