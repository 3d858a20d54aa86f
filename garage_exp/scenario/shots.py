"""What a scenario becomes: the shot list (where every actor stands in each frame) and its variants."""

from __future__ import annotations

from dataclasses import dataclass, field, fields


from garage_exp.scenario.schema import ActorConf
from garage_exp.core.errors import GarageError
from garage_exp.core.plain import as_object, thawed
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
    """Actor nodes as ActorConf objects; a key forced past the schema (`+case.actors.x.key=...`) is refused."""
    known = {f.name for f in fields(ActorConf)}
    for name, node in (nodes or {}).items():
        extra = sorted(set(node.keys()) - known)
        if extra:
            raise GarageError(f"unknown key {extra[0]!r} (an actor has {', '.join(sorted(known))})",
                              f"{prefix}.{name}.{extra[0]}")
    from garage_exp.scenario.actors import resolve_type

    return {str(n): resolve_type(typed(a, ActorConf), f"{prefix}.{n}") for n, a in (nodes or {}).items()}


def typed(node, schema: type):
    """A group's values as the dataclass of its schema: a config node's own (as_object), or plain settings'
    (`Settings`, whose keys are the schema's fields). Needed where fields are replaced (dataclasses.replace) or
    a key shadows a dict's method (the motion's `values`)."""
    obj = as_object(node)
    return schema(**thawed(obj)) if isinstance(obj, dict) else obj
