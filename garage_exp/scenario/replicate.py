"""Replicates: the same scenario again with variation that should not matter to the question asked.

Replicate 0 is the scenario as written. Replicate k >= 1 draws, from a generator seeded by (seed, k) alone, a
lateral offset and a yaw for every variant's target, a lateral offset for the ego, and the target's model from
its size class and colour (instead of the palette's pinned model); every other model the scenario leaves to
chance is drawn from the same generator. So replicate k is the same in every cell of a sweep and in every rerun:
cells compare like with like (common random numbers), and a cell's replicates show how much a result owes to
one particular car standing in one particular spot.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from garage_exp.core.errors import Infeasible
from garage_exp.scenario.shots import CaseSetup

EGO = "ego"
ATTEMPTS = 8  # draws of a replicate tried in turn while its actors overlap


def replicate_rng(seed: int, k: int, attempt: int = 0) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(k)] + ([attempt] if attempt else []))


def jitter(spec, rng: np.random.Generator, job, library):
    """A function that moves a case's actors for one replicate at a given scale: `adjust(conf, targets, scale)`.
    The draws are made once, on first use, in the scenario's actor order, so every scale moves the same way."""
    draws: dict[str, tuple[float, float, str]] = {}

    def draw(name: str, actor, is_target: bool) -> tuple[float, float, str]:
        if name not in draws:
            offset, yaw = (float(v) for v in rng.uniform(-1.0, 1.0, size=2))
            model = ""
            if is_target and spec.models and pinned(actor, job.palette):
                # as the build draws an unpinned target (scenario/actors.py: vehicle_model)
                model = library.choose(size_class=actor.size or "medium", colour=actor.colour,
                                       kind=actor.body or "car", max_height=job.garage.ceiling_height - 0.1,
                                       rng=rng).name
            draws[name] = (offset, yaw, model)
        return draws[name]

    def adjust(conf: dict, targets: set[str], scale: float) -> dict:
        out = dict(conf)
        for name, actor in conf.items():
            if name == EGO:
                offset, _, _ = draw(name, actor, False)
                out[name] = replace(actor, offset=actor.offset + scale * spec.ego_offset * offset)
            elif name in targets:
                offset, yaw, model = draw(name, actor, True)
                # A person in a gap keeps its offset: replicates before the gap took one left them where they were.
                side = 0.0 if actor.between else scale * spec.offset * offset
                out[name] = replace(actor, offset=actor.offset + side,
                                    yaw=actor.yaw + scale * spec.yaw * yaw, model=model or actor.model)
        return out

    return adjust


def pinned(actor, palette) -> bool:
    """The palette pins this target's model (so that every run compares the same cars): a replicate draws it
    instead. Models the scenario leaves to chance are drawn by the build, from the replicate's generator."""
    if actor.kind != "vehicle" or actor.model or actor.role != "target":
        return False
    return actor.colour in palette.target_colours and bool(
        palette.target or actor.colour in (palette.target_models or {}))


def build_replicate(build, job, classified, library, k: int) -> CaseSetup:
    """Replicate k of the case. When its draws make two actors overlap (a jitter too wide, or a wider model in
    a neighbouring bay), it draws again from a generator seeded (seed, k, attempt) with half the jitter: still
    the same in every cell and every rerun."""
    for attempt in range(ATTEMPTS):
        rng = replicate_rng(job.seed, k, attempt)
        adjust = jitter(job.replicate, rng, job, library)
        try:
            return build(job, classified, library, rng, adjust=lambda c, t, s=0.5 ** attempt: adjust(c, t, s))
        except Infeasible:  # two actors in one another: draw again, closer in
            if attempt == ATTEMPTS - 1:
                raise
    raise AssertionError("unreachable")


def merge(first: CaseSetup, other: CaseSetup, k: int) -> CaseSetup:
    """Replicate k's actors join the scene under their own names (`target_black_r1`), its shots follow."""
    rename = {e.name: f"{e.name}_r{k}" for e in other.vehicles if e.name != EGO}
    for entity in other.vehicles:
        if entity.name != EGO:
            entity.name = rename[entity.name]
            first.vehicles.append(entity)
    for shot in other.shots:
        shot.index = len(first.shots)
        shot.replicate = k
        shot.poses = {rename[n]: p for n, p in shot.poses.items()}
        shot.target = rename[shot.target]
        first.shots.append(shot)
    first.used_bays = sorted(set(first.used_bays) | set(other.used_bays))
    # Every shot places every actor: another replicate's actors wait out of the scene (None), not where they
    # were first put.
    names = [e.name for e in first.vehicles if e.name != EGO]
    for shot in first.shots:
        shot.poses = {n: shot.poses.get(n) for n in names}
    return first
