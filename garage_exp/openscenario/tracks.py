"""A job's case as an export's tracks: each variant's shots (replicate 0) become its actors' tracks (where each
starts, where it ends, how fast, from when), from the case setup the job's preflight built (run/openscenario.py
hands it over; export.py writes the files). Handed the scene builder's typed settings (SceneSpec), never a
config node."""

from __future__ import annotations

import math

from garage_exp.openscenario.model import ExportInfo, Track
from garage_exp.scenario.build import along_value, frame_times, moves_ego
from garage_exp.scenario.shots import CaseSetup, Shot
from garage_exp.scenario.timing import speed_at, start_time
from garage_exp.scene.description import Pose

PERSON_SPEED = 1.4  # m/s: a static case's moved person walks through its placements at this pace


def variants(cfg, setup: CaseSetup) -> list[tuple[str, str, float | None, list[Track], list[str]]]:
    """Each variant as export.write takes it: (label, its target, its frames' step, its actors' tracks, notes)."""
    return [(label, shots[0].target, frame_step(shots), *tracks(cfg, setup, shots))
            for label, shots in variants_of(setup)]


def export_info(job, version: str, plan: str) -> ExportInfo:
    """The job's names and values the files carry; `job`: the scene builder's settings (SceneSpec)."""
    garage = job.garage
    return ExportInfo(version, str(job.case.name), str(job.case.site),
                      float(job.case.motion.step), plan, str(job.light.name), float(job.ego_speed),
                      float(garage.pillar_size), float(garage.ceiling_height), float(garage.wall_thickness))


def frame_step(shots: list[Shot]) -> float | None:
    """The motion's value from one frame to the next (listed values too); None for a single frame."""
    return round(abs(shots[1].position - shots[0].position), 6) if len(shots) > 1 else None


def variants_of(setup: CaseSetup) -> list[tuple[str, list[Shot]]]:
    """Each variant's shots of replicate 0, in the order the job runs them."""
    out: dict[str, list[Shot]] = {}
    for shot in setup.shots:
        if shot.replicate == 0:
            out.setdefault(shot.label, []).append(shot)
    return list(out.items())


def _same(a: Pose, b: Pose) -> bool:
    return math.hypot(a.x - b.x, a.y - b.y) < 1e-6 and abs(((a.yaw - b.yaw) + 180) % 360 - 180) < 1e-6


def _extended(first: Pose, last: Pose, v0: float, v1: float, end: float) -> Pose:
    """The pose at placement value `end`, from two poses at values v0 and v1: placements move an actor in a
    straight line, value for value (distance, offset, out, gap are metres)."""
    if abs(v1 - v0) < 1e-9:
        return last
    k = (end - v0) / (v1 - v0)
    return Pose(first.x + k * (last.x - first.x), first.y + k * (last.y - first.y), 0.0, last.yaw)


def tracks(cfg, setup: CaseSetup, shots: list[Shot]) -> tuple[list[Track], list[str]]:
    """Every actor of the variant as a Track; and notes on what the file cannot say (for its description)."""
    entities = {e.name: e for e in setup.vehicles}
    ego_speed = float(cfg.ego_speed) / 3.6
    driving = moves_ego(cfg.case)
    times = [s.time for s in shots]
    notes: list[str] = []
    out = [Track("ego", entities["ego"], shots[0].ego)]
    if driving and not _same(shots[0].ego, shots[-1].ego):
        out[0].end, out[0].speed = shots[-1].ego, ego_speed
    alongs = dict(cfg.case.motion.along or {}) if driving else {}
    values = [s.position for s in shots]
    for name, entity in entities.items():
        poses = [s.poses.get(name) for s in shots]
        if name == "ego" or poses[0] is None:
            continue
        track = Track(name, entity, poses[0])
        out.append(track)
        moved = [k for k in range(1, len(poses)) if poses[k] is not None and not _same(poses[k], poses[k - 1])]
        if not moved:
            continue
        along = alongs.get(name)
        if along is not None and not along.values:
            # when it sets off: at the ego's `at`, or timed to `meet` it (scenario/timing.py); as the ego's travel
            t_at = start_time(along, lambda x: frame_times([values[0], x], float(cfg.ego_speed))[1])
            reached = [along_value(along, t, t_at) for t in times]
            track.end = _extended(poses[0], poses[moved[-1]], reached[0], reached[moved[-1]], float(along.end))
            track.speed = float(along.speed)
            track.accelerate = float(along.accelerate or 0.0)
            track.trigger = ("ego_travel", round(t_at * ego_speed, 6)) if t_at > 0 else ("time", 0.0)
            if t_at < 0:  # already on its way at the first frame: it starts there at the speed it has then
                track.initial = speed_at(along, -t_at)
            if along.meet is not None:  # timed to meet the ego: where the ego is then
                track.meet = _extended(shots[0].ego, shots[-1].ego, values[0], values[-1], float(along.meet))
            continue
        first, last = moved[0] - 1, moved[-1]
        track.end = poses[last]
        if driving and times[last] > times[first]:
            track.speed = track.length / (times[last] - times[first])
            track.trigger = ("time", times[first])
        else:
            track.speed = PERSON_SPEED if entity.kind == "person" else ego_speed
            notes.append(f"{name}: a sweep of placements frame by frame, written as a move at {track.speed:.2f} m/s")
        if any(not _same(poses[k], poses[k - 1]) and abs(((poses[k].yaw - poses[k - 1].yaw) + 180) % 360 - 180) > 1e-6
               for k in moved):
            notes.append(f"{name}: its turning on the spot (yaw) is left out")
    return out, notes


def frame_clock(cfg, shots: list[Shot], moving: list[Track]) -> list[float]:
    """When, in the exported scenario's time, the job's each frame is: its own time where the ego drives; in a
    sweep of placements (the ego standing), when the moved actor, walking or driving its track at the nominal
    speed, reaches the frame's placement."""
    if moves_ego(cfg.case):
        return [s.time for s in shots]
    mover = next((t for t in moving if t.end is not None and t.speed > 0), None)
    if mover is None:
        return [0.0 for _ in shots]
    t0 = mover.trigger[1] if mover.trigger[0] == "time" else 0.0
    out = []
    for shot in shots:
        pose = shot.ego if mover.name == "ego" else shot.poses[mover.name]
        out.append(t0 + math.hypot(pose.x - mover.start.x, pose.y - mover.start.y) / mover.speed)
    return out
