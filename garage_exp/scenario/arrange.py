"""Occluder arrangements: actors of the `occluder` group's own, standing still around the site's focus (its
pillar; else halfway between the ego and its target) in every frame of any scenario."""

from __future__ import annotations

import math
from dataclasses import replace

from garage_exp.core.errors import GarageError
from garage_exp.scenario import actors as kinds
from garage_exp.scenario.place import check_overlaps, pose_in_bay, pose_relative
from garage_exp.scenario.shots import Shot, actor_confs
from garage_exp.scenario.sites import Site, site_bay
from garage_exp.scene.bays import bays as all_bays
from garage_exp.scene.description import Pose

EGO = "ego"


def arrange(job, classified, library, site: Site, bays: dict, rng, made: dict, shots: list[Shot],
            taken: set) -> None:
    """The occluder arrangement's own actors, static, around the site's focus, added to every shot."""
    extra = actor_confs(job.occluder.actors, "occluder.actors")
    if not extra:
        return
    for name in extra:
        if name in made:
            raise GarageError(f"the scenario already has an actor {name!r}", f"occluder.actors.{name}")
    focus = site.focus or sightline(shots[0])
    free = sorted((b for b in all_bays(classified, job.garage) if (b.i, b.j, b.index) not in taken),
                  key=lambda b: math.hypot(b.x - focus.x, b.y - focus.y))
    axis = (math.cos(math.radians(focus.yaw)), math.sin(math.radians(focus.yaw)))
    for name, a in extra.items():
        where = f"occluder.actors.{name}"
        bay = None
        if a.nearest_bay >= 0:
            if a.nearest_bay >= len(free):
                raise GarageError(f"only {len(free)} free bays", where + ".nearest_bay")
            bay = free[a.nearest_bay]
        elif a.relative != "focus":
            raise GarageError("an arrangement's actor stands in a nearest_bay or relative: focus", where)
        made[name] = kinds.make(name, a, job, library, site, bays, rng, where, bay=bay)
        if bay:
            pose = pose_in_bay(site, replace(a, bay=site_bay(bay)), made[name].extent[0], bays, where)
        else:
            pose = pose_relative(focus, axis, a)
        for shot in shots:
            shot.poses[name] = pose
    for shot in shots:
        poses = {EGO: shot.ego, **{n: p for n, p in shot.poses.items() if p is not None}}
        check_overlaps(poses, made, shot.label, shot.position, only=set(extra), where="occluder.actors")


def sightline(shot: Shot) -> Pose:
    """Halfway between the ego and its target in a shot, heading from the ego to the target."""
    t = shot.poses[shot.target]
    yaw = math.degrees(math.atan2(t.y - shot.ego.y, t.x - shot.ego.x))
    return Pose((shot.ego.x + t.x) / 2, (shot.ego.y + t.y) / 2, 0.0, yaw % 360.0)
