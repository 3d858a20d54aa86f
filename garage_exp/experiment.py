"""One job: build the garage for the case, render every shot, score the target with the detectors, log."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig

from garage_exp import results
from garage_exp.cases import CaseSetup, make_case
from garage_exp.errors import GarageError
from garage_exp.plan.classify import Classified
from garage_exp.scene.description import CameraSpec, Pose, Scene

log = logging.getLogger("garage_exp")
HIDDEN = Pose(0.0, 0.0, -500.0, 0.0)  # vehicles a shot does not use wait far below the floor


def build_scene(cfg: DictConfig, classified: Classified, library, rng) -> tuple[Scene, CaseSetup]:
    """The garage from the plan, the case's vehicles, parked cars by occupancy, cameras and modifiers."""
    from garage_exp.scene.modifiers import apply_modifiers, remove_entity, resize_pillar
    from garage_exp.scene.parking import park_vehicles
    from garage_exp.scene.structure import build_garage

    scene = build_garage(classified, cfg.garage, cfg.light)
    apply_modifiers(scene, classified, cfg.garage, cfg.get("modifiers") or {})
    setup = make_case(cfg, classified, library, rng)
    if setup.occluder:
        if cfg.occluder.kind == "none":
            remove_entity(scene, setup.occluder)
        elif cfg.occluder.kind != "pillar":
            raise GarageError(f"unknown occluder kind {cfg.occluder.kind!r} (pillar | none)", "occluder.kind")
        elif cfg.occluder.size is not None:
            resize_pillar(scene, setup.occluder, cfg.occluder.size, classified)
    scene.entities.extend(setup.vehicles)
    if cfg.palette.parked_occupancy > 0:
        scene.entities.extend(park_vehicles(classified, cfg.garage, cfg.palette, library, rng, scene,
                                            exclude=setup.used_bays))
    scene.cameras = cameras(cfg, setup)
    scene.background = not cfg.blank
    return scene, setup


def cameras(cfg: DictConfig, setup: CaseSetup) -> list[CameraSpec]:
    ego = next(v for v in setup.vehicles if v.role == "ego")
    roof = ego.extent[2] if cfg.camera.roof else 0.0
    out = []
    for cam in cfg.camera.cameras:
        if not 1.0 <= cam.fovy <= 170.0:
            raise GarageError(f"fovy {cam.fovy} is outside 1-170 degrees", f"camera.cameras.{cam.name}.fovy")
        if cam.width < 16 or cam.height < 16 or cam.width > 4096 or cam.height > 4096:
            raise GarageError(f"resolution {cam.width}x{cam.height} is outside 16-4096 px",
                              f"camera.cameras.{cam.name}")
        out.append(CameraSpec(cam.name, Pose(cam.x, cam.y, roof + cam.z, cam.yaw), pitch=cam.pitch, fovy=cam.fovy,
                              width=cam.width, height=cam.height))
    return out


def run_experiment(cfg: DictConfig, classified: Classified, out: Path, run) -> float:
    from tqdm import tqdm

    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.detect import Detector, score_target
    from garage_exp.groundtruth import ground_truth
    from garage_exp.render import get_renderer
    from garage_exp.scene.gltf import export_glb
    from garage_exp.sensor import make_sensor

    rng = np.random.default_rng(cfg.seed)
    library = VehicleLibrary()
    scene, setup = build_scene(cfg, classified, library, rng)
    detector = Detector.from_config(cfg.detector)
    sensor = make_sensor(cfg.sensor)
    renderer = get_renderer(max_lights=cfg.renderer.max_lights, shadows=cfg.renderer.shadows)
    renderer.load(scene)
    glb = export_glb(scene, out / "scene.glb")
    run.log_artifact(glb)

    frames_dir = out / "frames"
    frames_dir.mkdir(exist_ok=True)
    dataset = results.DatasetWriter(out / "dataset") if cfg.dataset else None
    sensor_rng = np.random.default_rng(cfg.seed + 1)
    rows, keep = [], {}
    table_path = out / "frames.csv"
    try:
        for shot in tqdm(setup.shots, desc=f"case {cfg.case.name}", unit="frame", leave=False):
            renderer.set_pose("ego", shot.ego)
            for name, pose in shot.poses.items():
                renderer.set_pose(name, pose if pose is not None else HIDDEN)
            for cam in scene.cameras:
                frame = renderer.render(cam.name)
                in_view = [v.name for v in scene.vehicles() if v.role != "ego" and shot.poses.get(v.name, v.pose)]
                silhouettes = renderer.unoccluded_ids(cam.name, in_view)
                truth = ground_truth(frame, silhouettes, scene, renderer.ids)
                rgb = sensor.apply(frame.rgb, sensor_rng)
                if not scene.background:
                    rgb = renderer.blank_composite(rgb, frame, [shot.target])
                dets = detector.detect(rgb)
                target = next((t for t in truth if t.name == shot.target), None)
                score = score_target(dets, target, truth, iou_threshold=cfg.detector.iou, match=cfg.detector.match,
                                     threshold=cfg.detector.threshold, classes=tuple(cfg.detector.classes))
                row = results.frame_row(shot, cam.name, target, score, detector.names)
                rows.append(row)
                if dataset is not None:
                    dataset.add(f"{shot.index:04d}_{cam.name}", rgb, truth, scene)
                keep[(shot.index, cam.name)] = (rgb, target, dets)
                if cfg.renderer.save_frames == "all":
                    results.save_frame(frames_dir / f"{shot.index:04d}_{cam.name}.png", rgb, target, dets, score)
                if len(keep) > 3 * len(scene.cameras):
                    keep = results.prune_key_frames(keep, rows)
    finally:
        table = pd.DataFrame(rows)
        table.to_csv(table_path, index=False)
        run.log_artifact(table_path)  # kept even when the job fails half-way
    summary = results.summarise(table, cfg.detector.threshold, primary=scene.cameras[0].name)
    run.log_series("confidence", table[table.camera == scene.cameras[0].name].composite.tolist())
    run.log_series("visible_fraction", table[table.camera == scene.cameras[0].name].visible_fraction.tolist())
    run.log_metrics(summary)
    plot = results.plot_confidence(table, out / "confidence.png", setup.position_label, cfg)
    run.log_artifact(plot)
    if cfg.renderer.save_frames != "none":
        for path in results.save_key_frames(keep, table, frames_dir):
            run.log_artifact(path, "frames")
    if dataset is not None:
        run.log_artifact(dataset.finish())
    print(results.one_line(cfg, summary, len(table)))
    return float(summary["difficulty"])
