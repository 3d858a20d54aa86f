"""A space's requirements (`search.require`, or a shipped space's `require:` block): every draw is checked from
its scene description before a pixel is rendered, and a draw that cannot meet them is rejected and redrawn, as
Scenic cuts its prior with `require` (rejection sampling). A trial is then never rendered, let alone scored, on a
target nothing could see.

A draw is accepted when at least one of its shots, seen by the case's scored camera, meets every requirement
(a one-shot scenario has one shot): the target's estimated visible fraction, its projected box height, its
distance and the share of its box outside the image (perception/sightlines.py). A rejected draw is told to Optuna as PRUNED with `rejected` (why) among its
attributes: it counts neither in the study's budget nor among its scenarios, and the samplers learn to avoid its
region as they avoid infeasible ones. The search reports how many draws its requirements accepted.

The search looks first at the case's placed actors alone (`first_look`), before the garage around them is built:
a draw whose target is too small, too far or cut by the image's edge is rejected there, as the built scene's
`judge` would reject it; the rest are judged on the built scene. A search's sweeper takes that look from the
draw's plain settings, before its config is composed (search/plain_draw.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from garage_exp.core.errors import GarageError
from garage_exp.perception.sightlines import Boxes, Sight, sight, static_boxes
from garage_exp.scene.description import Scene


@dataclass(frozen=True)
class Require:
    """The requirements, as plain numbers (unset: no bound)."""

    min_visible: float = 0.0
    min_box: float = 0.0
    max_distance: float = math.inf
    max_truncation: float = 1.0
    max_draws: int = 1000

    @classmethod
    def of(cls, node) -> "Require | None":
        """The `search.require` node's rule; None when it sets no bound."""
        values = {k: node.get(k) for k in ("min_visible", "min_box", "max_distance", "max_truncation")}
        if all(v is None for v in values.values()):
            return None
        return cls(float(values["min_visible"] or 0.0), float(values["min_box"] or 0.0),
                   math.inf if values["max_distance"] is None else float(values["max_distance"]),
                   1.0 if values["max_truncation"] is None else float(values["max_truncation"]),
                   int(node.get("max_draws", 1000)))

    def unmet(self, seen: Sight) -> list[str]:
        """The requirements this shot misses, worded with its estimate."""
        out = []
        if seen.visible < self.min_visible:
            out.append(f"visible {seen.visible:.2f} < {self.min_visible:g}")
        if seen.box_height < self.min_box:
            out.append(f"box {seen.box_height:.0f} px < {self.min_box:g}")
        if seen.distance > self.max_distance:
            out.append(f"distance {seen.distance:.1f} m > {self.max_distance:g}")
        if seen.truncation > self.max_truncation:
            out.append(f"truncation {seen.truncation:.2f} > {self.max_truncation:g}")
        return out


def check_require(node, where: str = "search.require") -> None:
    """The node's own values: fractions in 0-1, sizes and distances positive."""
    if node.get("min_visible") is not None and not 0.0 <= float(node.min_visible) <= 1.0:
        raise GarageError(f"{node.min_visible} is outside 0-1", f"{where}.min_visible")
    if node.get("min_box") is not None and float(node.min_box) < 0:
        raise GarageError(f"{node.min_box} px is negative", f"{where}.min_box")
    if node.get("max_truncation") is not None and not 0.0 <= float(node.max_truncation) <= 1.0:
        raise GarageError(f"{node.max_truncation} is outside 0-1", f"{where}.max_truncation")
    if node.get("max_distance") is not None and not float(node.max_distance) > 0:
        raise GarageError(f"{node.max_distance} m: a distance bound is positive", f"{where}.max_distance")
    if int(node.get("max_draws", 1000)) < 1:
        raise GarageError(f"{node.max_draws} draws: at least 1", f"{where}.max_draws")


@dataclass(frozen=True)
class Verdict:
    """A draw's check: `ok`, or `why` not (the best shot's unmet requirements); `checked` False when the scored
    camera's lens cannot be checked from geometry (then the render decides, ok is True); `best` the shot's
    estimate that came closest."""

    ok: bool
    why: str = ""
    checked: bool = True
    best: Sight | None = None


def judge(rule: Require, scene: Scene, setup, camera: str) -> Verdict:
    """Whether any shot of the case set-up (`scenario.CaseSetup`) meets the rule in `camera` (the scored one)."""
    movers = {v.name: v for v in setup.vehicles}
    return _judged(rule, static_boxes(scene, skip=tuple(movers)), setup, scene.cameras, camera)


def first_look(rule: Require, setup, cameras, camera: str) -> Verdict | None:
    """The rule on the case's actors alone, before the garage is built (its pillars, walls and parked cars):
    the rejection the full `judge` would give, or None when only the built garage can decide.

    Exact: the box's height, its truncation and the distance do not depend on the garage, and what the garage
    hides can only lower the visible fraction, so a shot that fails here fails there, and a draw none of whose
    shots passes here is rejected there too. Its `why` names what failed without the garage (a target the garage
    also hides is not said to be), and its estimate's `visible` is an upper bound. Four in five of the wide
    space's rejections are decided so (its box too small or cut by the image's edge), each sparing the build of a
    garage, its parked cars and its dressing (~25 ms)."""
    verdict = _judged(rule, Boxes.of([]), setup, cameras, camera)
    return None if verdict.ok else verdict


def _judged(rule: Require, static: Boxes, setup, cameras, camera: str) -> Verdict:
    spec = next(c for c in cameras if c.name == camera)
    movers = {v.name: v for v in setup.vehicles}
    best, best_unmet = None, None
    for shot in setup.shots:
        # The ego's own box is left out: it is fuller than its bonnet, which a roof camera looks over.
        actors = {name: (v, shot.poses.get(name)) for name, v in movers.items() if v.role != "ego"}
        if actors.get(shot.target, (None, None))[1] is None:
            continue
        seen = sight(static, actors, shot.target, shot.ego, spec)
        if seen is None:
            return Verdict(True, checked=False)
        unmet = rule.unmet(seen)
        if not unmet:
            return Verdict(True, best=seen)
        if best_unmet is None or len(unmet) < len(best_unmet) or (
                len(unmet) == len(best_unmet) and seen.visible > best.visible):
            best, best_unmet = seen, unmet
    if best is None:
        return Verdict(False, "no shot shows the target")
    return Verdict(False, "; ".join(best_unmet), best=best)
