"""Sites: the plan features a scenario stands at, as named paths (lane centre lines) and bays.

A site turns a feature the plan model finds (a corner, a bay beside a pillar, a straight lane) into geometry a
scenario can name: `path: approach, distance: 12` or `bay: far`. Each kind of site lists ALL the plan's sites of
its kind, in a fixed order whose first is the one the research's cases stand at (the corner, bay or T-junction
nearest the entrance, the longest straight lane): `case.site_index` picks one by its place in that order and
`case.site_draw` by a fraction of their count (`pick`); without either a case stands at the first, as it always
did. A kind is registered beside its builder (`@register_site`), as the project's other kinds are.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE
from garage_exp.plan.classify import Classified
from garage_exp.plan.features import UNIT, Corner, StraightRun, corners, entrance_distance, run_length, straight_runs
from garage_exp.plan.model import OPPOSITE, YAW
from garage_exp.scene.bays import Bay, bays, pillar_centre
from garage_exp.scene.description import Pose

MARGIN = 0.2  # an actor on a path keeps this much room to the path's ends (m)


@dataclass(frozen=True)
class Path:
    """A lane's centre line: points origin + s * axis for s in [lo, hi]; actors on it face `heading`."""

    origin: tuple[float, float]
    axis: tuple[float, float]  # a unit compass vector
    heading: float  # yaw (degrees) of an actor driving along the path
    lo: float
    hi: float
    cell: tuple[int, int] | None = None  # the plan cell (i, j) at distance 0, for messages

    def point(self, s: float, offset: float = 0.0) -> tuple[float, float]:
        """The point s along the path, `offset` to the left of the axis."""
        x, y = self.origin[0] + s * self.axis[0], self.origin[1] + s * self.axis[1]
        if offset:
            x, y = x - offset * self.axis[1], y + offset * self.axis[0]
        return x, y

    def along(self, x: float, y: float) -> float:
        """World coordinate of (x, y) along the axis (the path's own frame counts from its origin)."""
        return x * self.axis[0] + y * self.axis[1]

    def at_world(self, t: float) -> tuple[float, float]:
        """The point of the centre line whose world coordinate along the axis is t."""
        ax, ay = self.axis
        return self.origin[0] * (1 - abs(ax)) + t * ax, self.origin[1] * (1 - abs(ay)) + t * ay

    def room(self, length: float) -> tuple[float, float]:
        """Where the centre of an actor `length` long may stand on the path."""
        half = length / 2 + MARGIN
        return self.lo + half, self.hi - half


@dataclass
class SiteBay:
    bay: Bay
    facing: tuple[float, float]  # unit vector towards the lane (a parked car's nose)


@dataclass
class Site:
    name: str
    paths: dict[str, Path]
    bays: list[SiteBay] = field(default_factory=list)
    sides: dict[str, list[SiteBay]] = field(default_factory=dict)  # bays by side (`bay: right:2`)
    pillar: str | None = None  # entity name of the pillar the site is about (the `occluder` group's object)
    focus: Pose | None = None  # where occlusion happens (the pillar's centre, heading along the main lane)
    index: int = 0  # its place among the plan's sites of its kind (0: the default, nearest the entrance)
    cell: tuple[int, int] | None = None  # the plan cell it is about (i, j), for messages and listings


@dataclass(frozen=True)
class SiteKind:
    """A shipped kind of site: `find` lists the plan's sites of the kind (cheap plan features, in the kind's
    order: the first is the research's, nearest the entrance), `build` turns one into a Site; `none`: the line
    said when the plan has none."""

    name: str
    find: Callable[[Classified, Any], list]
    build: Callable[[Classified, Any, Any], Site]
    none: str


SITES: dict[str, SiteKind] = {}
_FOUND: dict = STATE.cache("scenario.sites.found", "job")  # (plan, kind, bay width, pillar size) -> features
# A case that does not fit its drawn site tries the next (scenario/build.py build_hosted), and a search asks for the
# same sites at every draw: a straight run's build tests every bay of the plan (963 builds in a 40-trial wide
# search, start-up probes included; about 2 % of the trial loop, docs/performance.md). A built site depends only
# on the plan, the kind, the bays' width, the pillars' size and its index: kept for the process, per plan object
# (held by the entry, so that its id is not reused while the entry lives), for the last 32 plans as the bays are
# (a search drawing plan.seed meets a new plan at most draws).
# Sites are not changed once built (their users read paths and bays); each caller gets its own shallow copy.
_BUILT: dict = STATE.cache("scenario.sites.built", "process")
BUILT_PLANS = 32


def register_site(name: str, find: Callable[[Classified, Any], list], none: str):
    """Register the decorated `build(classified, garage, feature) -> Site` as the site kind `name`."""

    def register(build):
        SITES[name] = SiteKind(name, find, build, none)
        return build

    return register


def compass(yaw: float) -> str:
    return min(YAW, key=lambda d: abs(((YAW[d] - yaw) + 180) % 360 - 180))


def site_bay(bay: Bay) -> SiteBay:
    return SiteBay(bay, UNIT[compass(bay.yaw)])


@register_site("corner", lambda classified, _garage: corners(classified),
               "no corner lane cell with a pillar at its inner corner (case 1 needs one)")
def corner_at(classified: Classified, garage, c: Corner) -> Site:
    """A corner lane cell with a pillar at its inner corner (features.corners: nearest the entrance first).
    `approach`: the lane into the bend, distance counted back from the corner cell's centre; `exit`: the lane
    after the bend, counted from the centre."""
    centre = classified.plan.cell_center(c.cell.i, c.cell.j)
    u, v = UNIT[c.approach], UNIT[c.exit]
    approach = Path(centre, (-u[0], -u[1]), YAW[c.approach], 0.0, c.approach_length, c.centre)
    exit_ = Path(centre, v, YAW[c.exit], 0.0, c.exit_length, c.centre)
    focus = Pose(*pillar_centre(classified.plan, c.pillar, garage.pillar_size), 0.0, YAW[c.approach])
    return Site("corner", {"approach": approach, "exit": exit_}, pillar=f"pillar_{c.pillar.a}_{c.pillar.b}",
                focus=focus, cell=c.centre)


def corner(classified: Classified, garage) -> Site:
    """The corner nearest the entrance (the research's case 1)."""
    return find_site("corner", classified, garage)


def bays_beside_pillars(classified: Classified, garage) -> list[tuple]:
    """Type3 bays facing a straight lane with a pillar at one of their lane-side corners, nearest the entrance
    first (then by cell and bay): (bay, pillar, side, lane cell) each, a bay once (its first pillar so found)."""
    plan = classified.plan
    dist = entrance_distance(plan)
    size = garage.pillar_size  # read once: a config node's attribute costs ~50 us, asked bays x pillars x 4 times
    centres = [(pillar, pillar_centre(plan, pillar, size)) for pillar in classified.pillars]
    found = []
    for bay in bays(classified, garage):
        if bay.type != "type3":
            continue
        side = compass(bay.yaw)
        u = UNIT[side]
        lane_cell = plan.cell_at(bay.x + u[0] * (bay.depth / 2 + 0.5), bay.y + u[1] * (bay.depth / 2 + 0.5))
        if lane_cell is None or classified.cell(*lane_cell).type != "straight":
            continue
        front = (bay.x + u[0] * bay.depth / 2, bay.y + u[1] * bay.depth / 2)
        perp = (-u[1], u[0])
        for pillar, (px, py) in centres:
            for s in (-1, 1):
                cx, cy = front[0] + s * perp[0] * bay.width / 2, front[1] + s * perp[1] * bay.width / 2
                if math.hypot(px - cx, py - cy) <= size:
                    found.append((dist[lane_cell], bay.i, bay.j, bay.index, bay, pillar, side, lane_cell))
    found.sort(key=lambda t: t[:4])  # stable: a bay's pillars stay in the order found
    seen, out = set(), []
    for *_, bay, pillar, side, lane_cell in found:
        if (bay.i, bay.j, bay.index) not in seen:
            seen.add((bay.i, bay.j, bay.index))
            out.append((bay, pillar, side, lane_cell))
    return out


@register_site("bay_beside_pillar", bays_beside_pillars,
               "no Type3 bay facing a straight lane with a pillar beside it (the site bay_beside_pillar needs one)")
def bay_beside_pillar_at(classified: Classified, garage, found: tuple) -> Site:
    """A Type3 bay facing a straight lane with a pillar at one of its lane-side corners. Bay 0 is that bay;
    `lane` runs in front of it, left to right as a car parked nose to the lane sees it, distance 0 on the bay's
    axis."""
    plan = classified.plan
    bay, pillar, side, (lane_i, lane_j) = found
    lx, ly = plan.cell_center(lane_i, lane_j)
    left = LEFT_OF[side]
    right = {"N": "S", "S": "N", "E": "W", "W": "E"}[left]
    origin = (lx, bay.y) if side in "EW" else (bay.x, ly)  # the lane's centre line meets the bay's axis
    lane = Path(origin, UNIT[right], YAW[right], -run_length(plan, lane_i, lane_j, left),
                run_length(plan, lane_i, lane_j, right), (lane_i, lane_j))
    focus = Pose(*pillar_centre(plan, pillar, garage.pillar_size), 0.0, YAW[right])
    return Site("bay_beside_pillar", {"lane": lane}, [SiteBay(bay, UNIT[side])],
                pillar=f"pillar_{pillar.a}_{pillar.b}", focus=focus, cell=(bay.i, bay.j))


def bay_beside_pillar(classified: Classified, garage) -> Site:
    """The bay beside a pillar nearest the entrance (the research's case 2)."""
    return find_site("bay_beside_pillar", classified, garage)


@register_site("straight_run", lambda classified, _garage: straight_runs(classified),
               "no straight lane of 3+ cells with bays beside it (this case needs one)")
def straight_run_at(classified: Classified, garage, run: StraightRun) -> Site:
    """A straight lane of 3+ cells with bays beside it (features.straight_runs: longest first, then nearest the
    entrance). `lane`: its centre line in driving order, distance 0 at the first cell's centre; bays 0, 1, 2,
    ...: the bays on its first bay side, in driving order; `left:k`, `right:k`: the k-th bay on that side of the
    driving direction."""
    plan = classified.plan
    first = run.cells[0]
    h = UNIT[run.heading]
    lengths = [float(plan.C[c.j] if run.heading == "E" else plan.R[c.i]) for c in run.cells]
    lane = Path(plan.cell_center(first.i, first.j), h, YAW[run.heading], -lengths[0] / 2,
                sum(lengths) - lengths[0] / 2, (first.i, first.j))
    sides = {}
    for side in run.bay_sides:
        cells = {(c.i, c.j) for c in run.cells}
        u = UNIT[side]
        found = []
        for bay in bays(classified, garage):
            cell = plan.cell_at(bay.x - u[0] * (bay.depth / 2 + 0.5), bay.y - u[1] * (bay.depth / 2 + 0.5))
            # a bay on `side` of the run faces back towards the lane (its yaw points opposite to `side`)
            if cell in cells and abs(((bay.yaw - YAW[side]) + 180) % 360 - 180) > 90:
                found.append(bay)
        found.sort(key=lambda b: b.x * h[0] + b.y * h[1])
        sides[LEFT_OF[run.heading] == side and "left" or "right"] = [site_bay(b) for b in found]
    bays_first = sides.get("left" if run.bay_sides and LEFT_OF[run.heading] == run.bay_sides[0] else "right", [])
    return Site("straight_run", {"lane": lane}, bays_first, sides=sides, cell=(first.i, first.j))


def straight_run(classified: Classified, garage) -> Site:
    """The longest straight lane (the research's case 3)."""
    return find_site("straight_run", classified, garage)


def t_junction_cells(classified: Classified, _garage) -> list:
    dist = entrance_distance(classified.plan)
    return sorted(classified.of_type("t_junction"), key=lambda c: (dist[c.i, c.j], c.i, c.j))


@register_site("t_junction", t_junction_cells, "no T-junction lane cell (the site t_junction needs one)")
def t_junction_at(classified: Classified, garage, cell) -> Site:
    """A T-junction lane cell (nearest the entrance first). `stem`: the lane that ends at the junction, distance
    counted back from the junction cell's centre, actors facing the junction; `left` and `right`: the through
    lane as a car arriving on the stem sees it, distance from the centre, actors driving away from the
    junction."""
    plan = classified.plan
    stem = next(d for d in cell.lanes if OPPOSITE[d] not in cell.lanes)
    arrive = OPPOSITE[stem]  # heading of a car coming up the stem
    left, right = LEFT_OF[arrive], OPPOSITE[LEFT_OF[arrive]]
    centre = plan.cell_center(cell.i, cell.j)
    paths = {"stem": Path(centre, UNIT[stem], YAW[arrive], 0.0, run_length(plan, cell.i, cell.j, stem),
                          (cell.i, cell.j))}
    for name, d in (("left", left), ("right", right)):
        paths[name] = Path(centre, UNIT[d], YAW[d], 0.0, run_length(plan, cell.i, cell.j, d), (cell.i, cell.j))
    return Site("t_junction", paths, cell=(cell.i, cell.j))


def t_junction(classified: Classified, garage) -> Site:
    """The T-junction nearest the entrance."""
    return find_site("t_junction", classified, garage)


LEFT_OF = {"E": "N", "N": "W", "W": "S", "S": "E"}  # the compass side to the left of a heading


def cruising_lanes(classified: Classified, _garage) -> list[tuple[str, Any]]:
    """The lanes to cruise past bays: every straight run of 3+ cells (longest first), then every corner's
    approach (nearest the entrance first)."""
    return [("run", r) for r in straight_runs(classified)] + [("corner", c) for c in corners(classified)]


@register_site("lane_bays", cruising_lanes, "no corner lane cell with a pillar at its inner corner (case 1 needs one)")
def lane_bays_at(classified: Classified, garage, lane_of: tuple[str, Any]) -> Site:
    """A lane to cruise past bays (the slot-finding case): a straight run (its lane in driving order), or the
    lane into a corner, driven towards the corner. `lane`: its centre line in driving order; bays 0, 1, ...:
    every bay whose entrance opens on the lane, in driving order; `left:k`, `right:k`: the k-th on that side.
    The default (the first) is the longest straight lane where the plan has one, else the lane into the corner
    nearest the entrance."""
    what, feature = lane_of
    if what == "run":
        site = straight_run_at(classified, garage, feature)
        return _with_lane_bays(classified, garage, site.paths["lane"], "lane_bays", site.cell)
    approach = corner_at(classified, garage, feature).paths["approach"]
    # driven towards the corner: distance 0 at the lane's far end, the corner cell's centre at its end
    ax, ay = -approach.axis[0], -approach.axis[1]
    far = approach.point(approach.hi)
    lane = Path(far, (ax, ay), compass_yaw((ax, ay)), 0.0, approach.hi, approach.cell)
    return _with_lane_bays(classified, garage, lane, "lane_bays", feature.centre)


def lane_bays(classified: Classified, garage) -> Site:
    """The longest straight lane where the plan has one, else the lane into the corner nearest the entrance."""
    return find_site("lane_bays", classified, garage)


def compass_yaw(axis: tuple[float, float]) -> float:
    return next(YAW[d] for d, u in UNIT.items() if abs(u[0] - axis[0]) < 1e-9 and abs(u[1] - axis[1]) < 1e-9)


def _with_lane_bays(classified: Classified, garage, lane: Path, name: str, cell=None) -> Site:
    plan = classified.plan
    steps = max(2, int(math.ceil((lane.hi - lane.lo) / 0.25)))
    cells = {plan.cell_at(*lane.point(lane.lo + (lane.hi - lane.lo) * k / steps)) for k in range(steps + 1)}
    cells.discard(None)
    sides: dict[str, list[SiteBay]] = {"left": [], "right": []}
    found = []
    for bay in bays(classified, garage):
        sb = site_bay(bay)
        front = (bay.x + sb.facing[0] * (bay.depth / 2 + 0.5), bay.y + sb.facing[1] * (bay.depth / 2 + 0.5))
        if plan.cell_at(*front) not in cells:
            continue
        cross = lane.axis[0] * (bay.y - lane.origin[1]) - lane.axis[1] * (bay.x - lane.origin[0])
        found.append((lane.along(bay.x, bay.y), "left" if cross > 0 else "right", sb))
    found.sort(key=lambda t: t[0])
    for _, side, sb in found:
        sides[side].append(sb)
    return Site(name, {"lane": lane}, [sb for *_, sb in found], sides=sides, cell=cell)


# --- one site among the plan's sites of its kind ----------------------------------------------------------------

def shipped(site, where: str = "case.site") -> SiteKind:
    """The registered kind a case's `site` names; GarageError for an unknown name or the old dotted form."""
    if "." in site:  # the old form, a function's dotted name as the site's name
        raise GarageError(f"site {site!r} names a function: write it as site: {{_target_: {site}}} (on the command "
                          f"line case.site={{_target_:{site}}})", where)
    try:
        return SITES[site]
    except KeyError:
        raise GarageError(f"unknown site {site!r} (have {', '.join(sorted(SITES))}, or your own function: "
                          "{_target_: module.name})", where) from None


def features_of(site: str, classified: Classified, garage) -> list:
    """The plan's sites of a shipped kind as plan features, in the kind's order; GarageError (the kind's line,
    naming the plan's file) when it has none."""
    kind = shipped(site)
    # The features of a plan, asked twice a job (the pick, then the build) and costly on a big plan (1.2 s for
    # the 1,244 bays beside pillars of garage39x45): kept for the job, with the plan object they came from.
    key = (id(classified), site, float(garage.bay_width), float(garage.pillar_size))
    hit = _FOUND.get(key)
    if hit is None or hit[0] is not classified:
        hit = _FOUND[key] = (classified, kind.find(classified, garage))
    found = hit[1]
    if not found:
        raise GarageError(kind.none, classified.plan.source)
    return found


def site_count(site, classified: Classified, garage) -> int:
    """How many sites of the kind `site` names the plan has (>= 1; GarageError when none, or for a site of your
    own, which is one function, not a kind with sites to pick among)."""
    if not isinstance(site, str):
        raise GarageError(f"case.site_index and case.site_draw pick among a shipped kind's sites ({', '.join(SITES)});"
                          f" {site.get('_target_')} is a function of your own", "case.site_index")
    return len(features_of(site, classified, garage))


def pick(count: int, index=None, draw=None, kind: str = "", plan: str = "") -> int:
    """The index `case.site_index` or `case.site_draw` names among `count` sites (0 without either): an index
    past the count is a GarageError; a draw in [0, 1) is floor(draw * count), and 1.0 (the closed end of a
    search's interval) the last."""
    if draw is not None:
        return min(int(math.floor(float(draw) * count)), count - 1)
    index = 0 if index is None else int(index)
    if not 0 <= index < count:
        raise GarageError(f"{index} is past the {count} {kind} site(s) of plan {plan} (0..{count - 1})",
                          "case.site_index")
    return index


def every_site(site: str, classified: Classified, garage) -> list[Site]:
    """Every site of a shipped kind on the plan, in the kind's order (site 0: the default)."""
    kind = shipped(site)
    return [replace(kind.build(classified, garage, f), index=k)
            for k, f in enumerate(features_of(site, classified, garage))]


def find_site(site, classified: Classified, garage, index: int | None = None, draw: float | None = None) -> Site:
    """A shipped site by name (`site: corner`): the first of the plan's sites of that kind, or the one `index`
    (`case.site_index`) or `draw` (`case.site_draw`) picks; or a user's own, named by `_target_` like every
    component a config names: `site: {_target_: my_sites.ramp, ...}` is built through core.plugins.build, called
    with (classified, garage) and the node's other keys, in a module allowed by $GARAGE_EXP_MODIFIER_MODULES."""
    if not isinstance(site, str):
        if index is not None or draw is not None:
            site_count(site, classified, garage)  # refused: one function, no sites to pick among
        from garage_exp.core.plugins import build

        made = build(site, "a site function", "case.site", classified, garage)
        if not isinstance(made, Site):
            raise GarageError(f"{site.get('_target_')} returned {type(made).__name__}, not a Site", "case.site")
        return made
    kind = shipped(site)
    found = features_of(site, classified, garage)
    k = pick(len(found), index, draw, site, classified.plan.name)
    key = (id(classified), float(garage.bay_width), float(garage.pillar_size))
    held = _BUILT.get(key)
    if held is None or held[0] is not classified:
        if len(_BUILT) >= BUILT_PLANS:
            del _BUILT[next(iter(_BUILT))]  # the oldest plan's
        held = _BUILT[key] = (classified, {})
    built = held[1]
    if (kind, k) not in built:  # the kind itself in the key: one registered anew under the same name is its own
        built[(kind, k)] = replace(kind.build(classified, garage, found[k]), index=k)
    return replace(built[(kind, k)])
