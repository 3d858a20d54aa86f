"""A scenario moved frame by frame from outside: placement values in, one frame's poses out.

A job's shot list fixes every frame in advance (build.py). A sequential adversary (garage_exp/gym) decides each
frame's values as it goes, so this module places the actors of one variant of the case for any values
({actor: {key: value}}), with build.py's own pieces: the same site, variants, actors (the entities the job's
preflight already made, so the scene loaded once keeps its models) and `resolve`.
"""

from __future__ import annotations

from dataclasses import replace

from garage_exp.core.errors import GarageError
from garage_exp.scenario import actors as kinds
from garage_exp.scenario.build import EGO, MOVABLE, PLACEMENT, resolve, variants
from garage_exp.scenario.shots import CaseSetup, actor_confs
from garage_exp.scenario.sites import find_site
from garage_exp.scene.description import Pose


class LiveScenario:
    """One variant of `job.case` on the classified plan, with the entities of `setup` (the job's case set-up)."""

    def __init__(self, job, classified, setup: CaseSetup, variant: int = 0):
        case = job.case
        self.site = find_site(case.site, classified, job.garage, index=setup.site_index)
        self.bays = {str(k): str(v) for k, v in (case.bays or {}).items()}
        runs, conf = variants(case, actor_confs(case.actors, "case.actors"), list(job.palette.target_colours))
        if not 0 <= variant < len(runs):
            raise GarageError(f"the case has {len(runs)} variant(s): 0..{len(runs) - 1}", "gym.variant")
        run = runs[variant]
        self.label, self.target = run.label, run.target
        actors = {n: conf[n] for n in [EGO, *run.show]}
        for key, value in run.set.items():
            name, _, attr = str(key).partition(".")
            if name in actors and attr in PLACEMENT:
                actors[name] = replace(actors[name], **{attr: value})
        self.actors = actors
        self.made = {e.name: kinds.Made(e, e.extent, [], f"case.actors.{e.name}") for e in setup.vehicles}
        missing = [n for n in actors if n not in self.made]
        if missing:
            raise GarageError(f"the scene has no entity for actor(s) {', '.join(missing)}", "case.actors")

    def value(self, actor: str, key: str) -> float:
        return float(getattr(self.actors[actor], key))

    def poses(self, values: dict[str, dict[str, float]]) -> tuple[Pose, dict[str, Pose | None]]:
        """(the ego's pose, every other entity's pose: None for those not in this variant) for these values."""
        placed = dict(self.actors)
        for name, keys in values.items():
            if name not in placed:
                raise GarageError(f"no actor {name!r} in this variant (have {', '.join(placed)})", "gym.movers")
            bad = [k for k in keys if k not in MOVABLE]
            if bad:
                raise GarageError(f"{bad[0]!r} is not a placement value ({' | '.join(MOVABLE)})", "gym.movers")
            placed[name] = replace(placed[name], **{k: float(v) for k, v in keys.items()})
        poses = resolve(placed, self.made, self.site, self.bays)
        return poses[EGO], {n: poses.get(n) for n in self.made if n != EGO}

