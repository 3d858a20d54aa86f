"""A job's slot frames: the bird's-eye view of each shot, its slot ground truth, exports, detection and score.

Active when the case asks for slots (`case.slots`) on a rig with fisheyes, or `camera.bev.enabled`. Each shot's
fisheye pictures (what the detectors get: after the sensor model) are stitched into the BEV (render/bev.py); the slot
ground truth for the ego's pose there (slots/truth.py) is exported (slots/export.py: slots/ under
the job's dir, logged), and the `slot_detector` group's detector runs on the BEV and is scored against the truth
(slots/results.py), fair slots only. Per frame: `slots.csv` (a row per BEV frame); per job:
the pooled metrics `slot_point_recall`, `slot_point_precision`, `slot_recall`, `slot_precision`,
`slot_occupancy_acc` and the truth's counts (`slot_truth_*`), logged with the job's other metrics. The job's
frame loop (run/frames.py) drives it, handing it what the scene builder is told (the job spec's SceneSpec: camera,
case, garage, materials, seed, wear), the `slot_detector` group as plain data and whether frames are saved.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from garage_exp.core.plain import Settings
from garage_exp.scene.lenses import rig_has

# slots.results' names -> the job's metric names
METRICS = {"point_recall": "slot_point_recall", "point_precision": "slot_point_precision",
           "slot_recall": "slot_recall", "slot_precision": "slot_precision",
           "occupancy_accuracy": "slot_occupancy_acc", "point_error_m": "slot_point_error_m"}


def wanted(job) -> bool:
    """A BEV is set on the rig, or the case asks for slots and the rig has fisheyes to stitch (a slot case on
    a pinhole rig runs as an object case, and says so). `job`: the scene builder's settings (SceneSpec), or a
    config's."""
    if job.camera.bev.enabled:
        return True
    if not job.case.slots:
        return False
    if rig_has(job.camera, "bev"):
        return True
    print(f"garage_exp: case {job.case.name} scores slots on a bird's-eye view of fisheye cameras; rig "
          f"{job.camera.name} has none, so no slot frames (camera=fisheye4)")
    return False


def bev_spec(job):
    from garage_exp.render.bev import spec_of

    return spec_of(job.camera.bev)


def finder(conf: Settings):
    """(detect, score, pool, metrics conf) from the `slot_detector` group (`lines` unless another is chosen)."""
    from garage_exp.slots.detector import load
    from garage_exp.slots.results import pool, score

    return load(conf), score, pool, conf.get("metrics")


@dataclass
class SlotFrames:
    job: object  # the scene builder's settings (scenario.spec.SceneSpec)
    save: bool  # the BEV frames are drawn and saved (renderer.save_frames is not none)
    scene: object
    out: Path
    spec: object
    maps: object
    world: list
    exports: object
    found_by: object = None
    waiting: dict = field(default_factory=dict)
    rows: list = field(default_factory=list)
    scores: list = field(default_factory=list)
    pictures: list = field(default_factory=list)  # the BEV frames written (for the run's artifacts)

    @classmethod
    def open(cls, job, detector: Settings, save: bool, prepared, out: Path) -> "SlotFrames":
        """`job`: the scene builder's settings (SceneSpec); `detector`: the `slot_detector` group."""
        from garage_exp.slots.export import SlotExports
        from garage_exp.slots.truth import world_bays
        from garage_exp.render.bev import bev_maps
        from garage_exp.scenario.assemble import marking_wear

        from garage_exp.scene.look import dress_for

        scene = prepared.scene
        ego = next(v for v in scene.vehicles() if v.role == "ego")
        spec = bev_spec(job)
        wear = marking_wear(job)
        # the paint texture of the materials' draw (replicate 0's: a replicate's own draw is close to it)
        texture = (dress_for(job.materials, int(job.seed), wear).paint_wear if str(job.materials.level) != "none"
                   else 0.0)
        return cls(job, save, scene, out, spec, bev_maps(scene.cameras, spec, ego.extent),
                   world_bays(prepared.classified, job.garage, wear, texture), SlotExports(out / "slots"),
                   finder(detector))

    def add(self, shot, camera: str, rgb: np.ndarray) -> None:
        """One camera's picture of a shot; the BEV frame is made once the shot's fisheyes are all in."""
        pictures = self.waiting.setdefault(shot.index, {})
        pictures[camera] = rgb
        if set(self.maps.cameras) <= set(pictures):
            self._frame(shot, self.waiting.pop(shot.index))

    def _frame(self, shot, pictures: dict) -> None:
        from garage_exp.slots.export import draw_frame
        from garage_exp.slots.truth import obstacles, slot_truth

        bev = self.maps.stitch({k: v for k, v in pictures.items() if k in self.maps.cameras})
        truth = slot_truth(self.world, self.spec, shot.ego, self.scene.cameras, self.maps,
                           obstacles(self.scene, shot.poses))
        stem = f"{shot.index:04d}_bev"
        self.exports.add(stem, bev, truth)
        fair = truth.fair
        row = {"shot": shot.index, "label": shot.label, "position": shot.position, "replicate": shot.replicate,
               "slots": len(truth.frame.slots), "fair": int(sum(fair)),
               "occupied": int(sum(bool(s.occupied) for s in truth.frame.slots)),
               "hidden_corners": sum(v == "hidden" for vis in truth.visibility for v in vis),
               "worn_corners": sum(v == "worn" for vis in truth.visibility for v in vis)}
        found = None
        if self.found_by is not None:
            detect, score, _, metrics = self.found_by
            found = detect(bev, self.spec.meters_per_pixel)
            scored = score(truth.frame, found, fair, metrics)
            self.scores.append(scored)
            row.update({k: float(v) for k, v in scored.items()})
            self._write_found(stem, found)
        self.rows.append(row)
        if self.save:  # drawn only to be saved
            from PIL import Image

            picture = draw_frame(bev, truth.frame)
            if found is not None:
                picture = draw_frame(picture, found, colour=(80, 200, 255), thickness=1)
            path = self.out / "frames" / f"{stem}.png"
            path.parent.mkdir(exist_ok=True)
            Image.fromarray(picture).save(path)
            self.pictures.append(path)

    def _write_found(self, stem: str, found) -> None:
        import json

        from garage_exp.slots.export import ps2_record

        (self.out / "slots" / "found").mkdir(exist_ok=True)
        (self.out / "slots" / "found" / f"{stem}.json").write_text(json.dumps(ps2_record(found)))

    def finish(self, run) -> dict:
        """Write slots.csv and the exports, log them, and return the job's slot metrics."""
        table = pd.DataFrame(self.rows)
        table.to_csv(self.out / "slots.csv", index=False)
        run.log_artifact(self.out / "slots.csv")
        run.log_artifact(self.exports.finish())
        for path in self.pictures:
            run.log_artifact(path, "frames")
        summary = {"slot_frames": float(len(table))}
        if len(table):
            summary.update({"slot_truth_slots": float(table.slots.mean()), "slot_truth_fair": float(table.fair.mean()),
                            "slot_truth_occupied": float(table.occupied.mean())})
        if self.found_by is not None and self.scores:
            pooled = self.found_by[2](self.scores)
            summary.update({name: float(pooled[key]) for key, name in METRICS.items() if key in pooled})
        return summary


def slot_line(summary: dict) -> str:
    """The job's slot result in one line."""
    parts = [f"{int(summary.get('slot_frames', 0))} BEV frames",
             f"{summary.get('slot_truth_slots', float('nan')):.1f} slots a frame",
             f"{summary.get('slot_truth_fair', float('nan')):.1f} fair"]
    for name in ("slot_recall", "slot_precision", "slot_point_recall", "slot_point_precision", "slot_occupancy_acc"):
        if name in summary:
            parts.append(f"{name[5:]} {summary[name]:.3f}")
    return "slots: " + ", ".join(parts)
