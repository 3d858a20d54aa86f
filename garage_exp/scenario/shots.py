"""What a scenario becomes: the shot list (where every actor stands in each frame) and its variants."""

from __future__ import annotations

from dataclasses import dataclass, field


from garage_exp.scenario.schema import ActorConf
from garage_exp.core.errors import GarageError
from garage_exp.core.plain import typed
from garage_exp.scene.description import Entity, Pose


@dataclass
class Shot:
    """One frame: the ego's pose, the pose of each case actor (None: not in the scene), the target."""

    index: int
    label: str  # the variant this frame belongs to: a colour, a placement ("far=large"), ...
    position: float  # the plot's x value: the moved placement value
    ego: Pose
    poses: dict[str, Pose | None]
    target: str
    replicate: int = 0  # which replicate of the scenario (garage_exp/scenario/replicate.py)
    time: float = 0.0  # seconds since the trajectory's first frame (the ego's travel over its speed; 0: static)


@dataclass
class CaseSetup:
    vehicles: list[Entity]  # the case's actors (ego included), vehicles and people
    shots: list[Shot]
    occluder: str | None = None  # the structure entity the case is about (a pillar)
    used_bays: list[tuple[int, int, int]] = field(default_factory=list)  # (i, j, k) kept free of parked cars
    position_label: str = "position (m)"
    site_index: int | None = None  # the site of its kind the case stands at (None: the first, as by default)


@dataclass
class Variant:
    label: str
    show: list[str]
    target: str
    set: dict


def actor_confs(nodes, prefix: str) -> dict:
    """Actors (ActorConf, or their values) as ActorConf objects with their `type` resolved; a key forced past the
    schema (`+case.actors.x.key=...`) is refused (core.plain.typed)."""
    from garage_exp.scenario.actors import resolve_type

    return {str(n): resolve_type(typed(ActorConf, a, f"{prefix}.{n}"), f"{prefix}.{n}")
            for n, a in (nodes or {}).items()}
