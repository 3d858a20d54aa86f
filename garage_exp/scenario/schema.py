"""A scenario's config nodes (the `case` and `occluder` groups, their actors, motions and variants, and the
`replicate` node), beside the code that builds and checks them in this package (scenario/build.py, shots.py,
replicate.py), registered as config nodes here (core/config_nodes.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from garage_exp.core.config_nodes import MISSING, register_node


@dataclass
class ActorConf:
    """One actor of a scenario. Every value is a plain key (`case.actors.target.offset=0.4`), so sweeps and
    searches reach it. Placement: exactly one of `path`, `bay`, `between` or `relative`."""

    role: str = "target"  # ego | target | occluder | parked | moving
    kind: str = "vehicle"  # vehicle | person | box
    # vehicle: a model by name, or drawn by size class (small | medium | large), colour and body (car, van, ...);
    # colour `palette`: one copy per palette target colour, one variant each (the research's black and white cars)
    model: str = ""
    size: str = ""
    colour: str = ""
    body: str = ""
    # person: age group, height (m, None: the group's usual), build, pose (standing | walking | crouching),
    # clothing palette
    age: str = "adult"
    height: Optional[float] = None
    build: str = "average"
    gender: str = "neutral"
    pose: str = "standing"
    clothing: str = "default"
    # box (a static occluder): its size in metres (height shared with people), colour by name
    length: Optional[float] = None
    width: Optional[float] = None
    # placement
    path: str = ""  # a path of the site: `distance` metres along it, `offset` to its left
    distance: float = 0.0
    offset: float = 0.0
    yaw: float = 0.0  # degrees, added to the heading the placement gives
    align: str = "centre"  # centre: distance is the actor's centre; start: its rear, from the path's start
    clip: bool = False  # with path: a distance the path has no room for is trimmed to its room (else an error);
    # with relative: trimmed to the room of the path the other actor stands on
    before: str = ""  # with path: distance counted back from this bay, or from this actor
    bay: str = ""  # in this bay of the site (a name from `bays`, or an index), nose to the lane
    gap: Optional[float] = None  # in a bay: front bumper this far behind the bay line (None: centred); with
    # `relative`: it stands before the other actor (towards the ego), this much free floor between them
    between: list[str] = field(default_factory=list)  # in the gap between two bays ...
    out: float = 0.0  # ... this far past the bay line into the lane
    relative: str = ""  # `distance` ahead of this actor (or of `focus`) along its heading, `offset` to its left
    nearest_bay: int = -1  # in the k-th free bay nearest the site's focus (0: the nearest), nose to the lane
    # One key for what the actor is (scenario/actors.py: resolve_type): a vehicle model's name (any of the
    # library's), `child`, `adult`, `crouching` (an adult crouching) or `pillar` (a box painted as the pillars);
    # empty: `kind`, `model`, `age`, `pose` as written. A search's `choice(...)` over vehicles and people in one
    # factor.
    type: str = ""
    # A person's height as a fraction 0-1 of its age group's range (assets/people.py: STATURE, the 5th to 95th
    # percentile); None: `height` (or the group's usual). One factor for children and adults alike.
    stature: Optional[float] = None
    # A vehicle's paint (scenario/actors.py: paint), HLS: hue in degrees (0-360), saturation and lightness 0-1;
    # all None: the model's own paint. Any one set paints it (the others from 0 hue, 0.5 saturation, 0.5 lightness).
    hue: Optional[float] = None
    saturation: Optional[float] = None
    lightness: Optional[float] = None


@dataclass
class OccluderConf:
    """The occluder arrangement, composed with any scenario: the site's pillar kept or removed, and actors of
    its own placed around the site's focus (the pillar; else halfway between the ego and the target)."""

    name: str = "pillar"
    kind: str = "pillar"  # pillar: the site's pillar stands | none: it is removed
    size: Optional[float] = None  # the pillar's side (m); None: as the garage (and `pillar` factor) has it
    actors: dict[str, ActorConf] = field(default_factory=dict)  # shown in every variant of the scenario


@dataclass
class AlongConf:
    """An actor moving at the same time as the motion's (a person stepping out while the ego drives): its
    placement value `key` goes from `start` towards `end` at `speed` (m/s) from the frame where the motion's
    value passes `at` (None: from the first frame), or timed to reach `end` as the motion's value passes `meet`.
    The time of a frame is the ego's travel over `ego.speed`."""

    key: str = "out"  # distance | offset | yaw | out | gap
    start: float = 0.0
    end: float = 0.0
    speed: float = 1.4  # m/s (1.4: an adult's walking speed)
    at: Optional[float] = None
    values: list[float] = field(default_factory=list)  # instead: the value at each frame of the motion (the last
    # one held after), as an adversary's episode moved it (garage_exp/gym/export.py)
    accelerate: float = 0.0  # metres from standstill to `speed` at a constant acceleration (0: at speed at once;
    # Euro NCAP's pedestrian targets reach theirs after 1 m)
    meet: Optional[float] = None  # instead of `at`: start so as to reach `end` when the motion's value passes
    # `meet` (a synchronised arrival, as OpenSCENARIO's SynchronizeAction and the Euro NCAP protocols time it)
    path: list[list[float]] = field(default_factory=list)  # instead of start/end: the [distance, offset] points
    # it walks through at `speed`, the first where it stands (an imported polyline trajectory's vertices); it
    # turns as each leg turns from the first (key: distance or offset, the one an exported file reads)


@dataclass
class MotionConf:
    """The per-frame sweep: one placement value of one actor (its copies, for a palette-coloured actor)."""

    actor: str = ""  # empty: a static scenario (one frame per variant); `target` with no actor so named: each
    # variant's target
    key: str = "distance"  # distance | offset | yaw | out | gap
    start: Optional[float] = None
    end: Optional[float] = None
    step: float = 0.5
    values: list[float] = field(default_factory=list)  # instead of start/end/step
    along: dict[str, AlongConf] = field(default_factory=dict)  # actor -> its motion at the same time (the ego's)


@dataclass
class VariantConf:
    """A run of frames with some of the actors standing (the others wait out of the scene)."""

    label: str = ""  # the frame table's label; empty: the shown actors' names
    show: list[str] = field(default_factory=list)  # the actors besides the ego; empty: all of them
    target: str = ""  # the actor scored; empty: the scenario's target
    set: dict[str, Any] = field(default_factory=dict)  # "actor.key": value for this variant only


@dataclass
class CaseConf:
    """A scenario (one YAML file of the `case` group): a site of the plan, actors, a motion, variants."""

    name: str = MISSING
    # corner | bay_beside_pillar | straight_run | ... (garage_exp/scenario/sites.py), or your own site function:
    # {_target_: my_sites.ramp, ...its keyword arguments}
    site: Any = MISSING
    # which of the plan's sites of that kind (scenario/sites.py: ordered with the one nearest the entrance, or the
    # longest straight lane, first): site_index picks by its place (null: the first, the research's), site_draw
    # by a fraction of their count in [0, 1] (floor(draw x count), 1.0 the last: a search over garages with other
    # counts); a
    # site that does not host the case passes it to the next in order (docs/scenarios.md)
    site_index: Optional[int] = None
    site_draw: Optional[float] = None
    position_label: str = "position (m)"  # the plot's x axis: what the motion moves
    bays: dict[str, str] = field(default_factory=dict)  # names for the site's bays (far: 3, mine: right:2)
    keep_free: list[str] = field(default_factory=list)  # bays kept free of the palette's parked cars (besides
    # those the actors stand in)
    actors: dict[str, ActorConf] = field(default_factory=dict)
    motion: MotionConf = field(default_factory=MotionConf)
    variants: list[VariantConf] = field(default_factory=list)
    target: str = ""  # the actor scored when a variant does not say; empty: the actor with role target
    slots: bool = False  # score parking-slot finding on a bird's-eye view of the fisheye rig (camera.bev)
    camera: str = ""  # the rig's camera whose frames score the case (its summary, `late`): a reversing ego's
    # `rear`; empty: the rig's first camera
    # One-shot scenarios: K frames evenly along the motion (the first and the last among them), the trajectory's own
    # frames (its times and co-motions as the whole trajectory has them); None: every frame (a trajectory).
    # frames=1 is the motion's first frame: a scenario is one picture, and a search's budget counts scenarios.
    frames: Optional[int] = None


@dataclass
class ReplicateConf:
    """What changes between the replicates of a cell (replicate 0 is the scenario as written): uniform draws in
    +-these ranges, seeded by (seed, replicate) so replicate k is the same in every cell and every rerun."""

    offset: float = 0.3  # each target's lateral offset (m)
    yaw: float = 5.0  # each target's yaw (degrees)
    ego_offset: float = 0.3  # the ego's lateral position (m)
    models: bool = True  # each vehicle target's model drawn from its size class and colour


register_node("occluder", OccluderConf, group=True)
register_node("case", CaseConf, group=True)
register_node("replicate", ReplicateConf)
