"""What an export says about a job and its actors: the job's names and values (`ExportInfo`), each actor's
track (`Track`), and an actor's OpenSCENARIO reference point (a vehicle's rear axle; a person's or a box's
footprint centre)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from garage_exp.scene.description import Entity, Pose


@dataclass(frozen=True)
class ExportInfo:
    """What the files say about the job besides its tracks (built from the job's config by run/openscenario.py):
    the version written, the names and values in each scenario's description, the garage's dimensions."""

    version: str  # export.openscenario_version
    case: str
    site: str
    step: float  # case.motion.step: a variant's step when its frames do not say one
    plan: str
    light: str
    ego_speed: float  # km/h
    pillar_size: float
    ceiling_height: float
    wall_thickness: float


@dataclass
class Track:
    """One actor in one variant: where it starts and, if it moves, where it ends, how fast and from when."""

    name: str
    entity: Entity
    start: Pose
    end: Pose | None = None  # None: it stands still
    speed: float = 0.0  # m/s
    trigger: tuple[str, float] = ("time", 0.0)  # ("time", s) | ("ego_travel", m travelled by the ego)
    accelerate: float = 0.0  # metres from standstill to `speed` at a constant acceleration (0: a step)
    initial: float = 0.0  # m/s it already has at the start (a walk under way at the first frame)
    meet: Pose | None = None  # where the ego is when this actor reaches its end (a timed arrival: `meet`)

    @property
    def length(self) -> float:
        return math.hypot(self.end.x - self.start.x, self.end.y - self.start.y) if self.end else 0.0

    @property
    def velocity(self) -> float:
        """Its speed, negative when it moves against its heading (a reversing ego, as OpenSCENARIO says it)."""
        if self.end is None:
            return 0.0
        h = math.radians(self.start.yaw)
        ahead = (self.end.x - self.start.x) * math.cos(h) + (self.end.y - self.start.y) * math.sin(h)
        return -self.speed if ahead < -1e-9 else self.speed


REAR_AXLE_IN = 0.9  # m: a vehicle's rear axle this far in from its rear bumper (and the front axle from its front)


def axle_offset(entity: Entity) -> float:
    """How far the bounding box's centre lies ahead of the entity's OpenSCENARIO reference point: a vehicle's is
    its rear axle (OpenSCENARIO 1.2, 'Coordinate systems': the vehicle's reference point), a person's or a box's
    its footprint's centre."""
    if entity.kind in ("person", "box"):
        return 0.0
    return max(entity.extent[0] / 2 - REAR_AXLE_IN, 0.0)


def reference(pose: Pose, entity: Entity) -> Pose:
    """Our pose (the footprint's centre) as the entity's reference point."""
    back = axle_offset(entity)
    h = math.radians(pose.yaw)
    return Pose(pose.x - back * math.cos(h), pose.y - back * math.sin(h), 0.0, pose.yaw)
