"""A scenario (one `case` YAML) turned into a shot list: where the ego, its target and every other actor stand
in each frame.

The scenario names a site (a plan feature), its actors (kind, role, placement), one motion (an actor's
placement value swept frame by frame) and variants (which actors stand, run one after another). Every value is
a config key, so a sweep or a search can set it by an override.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from functools import partial

import numpy as np

from garage_exp.core.errors import GarageError

from garage_exp.plan.classify import Classified
from garage_exp.scenario import actors as kinds
from garage_exp.scenario.arrange import arrange
from garage_exp.scenario.replicate import build_replicate, merge
from garage_exp.scenario.schema import VariantConf
from garage_exp.scenario.shots import CaseSetup, Shot, Variant, actor_confs
from garage_exp.scenario.place import (check_overlaps, farthest, no_room, pose_between, pose_in_bay,
                                       pose_on_path, pose_relative, room, site_bay, site_path, sweep_clash)
from garage_exp.scenario.sites import Site, find_site, pick, site_count
from garage_exp.scenario.spec import SceneSpec
from garage_exp.scenario.timing import start_time, travelled
from garage_exp.scene.camera import scored_camera
from garage_exp.scene.description import Pose

log = logging.getLogger("garage_exp")
EGO = "ego"
PALETTE = "palette"  # an actor's colour: one copy per palette target colour, one variant each
MOVABLE = ("distance", "offset", "yaw", "out", "gap")
PLACEMENT = (*MOVABLE, "path", "align", "before", "bay", "between", "relative")
GAP_SEARCH = 3.0  # m each side of a gap's middle that an overlap message looks for a person's room in


def check_case(job: SceneSpec) -> None:
    """What a scenario's values say before the plan is known (the rest needs the site: `make_case`)."""
    if int(job.replicates) < 1:
        raise GarageError(f"replicates must be >= 1, got {job.replicates}", "replicates")
    for key in ("offset", "yaw", "ego_offset"):
        if float(getattr(job.replicate, key)) < 0:
            raise GarageError(f"a range is >= 0, got {getattr(job.replicate, key)}", f"replicate.{key}")
    try:
        _check_site_pick(job.case)
        _check_motion(job.case)
        scored_camera(job.camera, str(job.case.camera or ""))
    except GarageError as exc:
        raise exc.again(str(exc), level_file(job, "case")) from None


def _check_site_pick(case) -> None:
    """`case.site_index` (>= 0) or `case.site_draw` (in [0, 1]: 1.0, a search interval's closed end, is the last
    site), not both; the count is the plan's (make_case)."""
    index, draw = case.site_index, case.site_draw
    if index is not None and draw is not None:
        raise GarageError(f"give site_index or site_draw, not both (have {index} and {draw})", "case.site_draw")
    if index is not None and int(index) < 0:
        raise GarageError(f"a site's index is >= 0, got {index}", "case.site_index")
    if draw is not None and not 0.0 <= float(draw) <= 1.0:
        raise GarageError(f"a draw is in [0, 1], got {draw}", "case.site_draw")


def _check_motion(case) -> None:
    frames = case.frames
    if frames is not None and not (isinstance(frames, int) and not isinstance(frames, bool) and frames >= 1):
        raise GarageError(f"frames must be a whole number >= 1 (or null: every frame), got {frames!r}",
                          "case.frames")
    if case.motion.actor and not float(case.motion.step) > 0:
        raise GarageError(f"step must be positive, got {case.motion.step}", "case.motion.step")
    if case.motion.key not in MOVABLE:
        raise GarageError(f"motion key {case.motion.key!r} is not a placement value ({' | '.join(MOVABLE)})",
                          "case.motion.key")
    for name, along in (case.motion.along or {}).items():
        where = f"case.motion.along.{name}"
        if not moves_ego(case):
            raise GarageError("an actor moves along with the ego's motion (a frame's time is the ego's travel "
                              f"over ego.speed); this motion moves {case.motion.actor or 'nothing'!r}", where)
        if along.key not in MOVABLE:
            raise GarageError(f"key {along.key!r} is not a placement value ({' | '.join(MOVABLE)})", where + ".key")
        if float(along.speed) < 0:
            raise GarageError(f"{along.speed} m/s is negative", where + ".speed")
        if float(along.accelerate or 0.0) < 0:
            raise GarageError(f"{along.accelerate} m is negative", where + ".accelerate")
        path = along.path or []
        if path and (len(path) < 2 or any(len(p) != 2 for p in path)):
            raise GarageError("a path is two or more [distance, offset] points, the first where it stands",
                              where + ".path")
        if path and along.key not in ("distance", "offset"):
            raise GarageError(f"an actor on a path moves its distance and offset, not {along.key!r}", where + ".key")
        if along.meet is not None and along.at is not None:
            raise GarageError("give `at` (when it sets off) or `meet` (when it arrives), not both", where + ".meet")
        # (`meet` may lie past the motion's end: the last frames come before the arrival the walk is timed for)
        if along.at is not None and not along.values and case.motion.start is not None \
                and case.motion.end is not None:
            lo, hi = sorted((float(case.motion.start), float(case.motion.end)))
            if not lo <= float(along.at) <= hi:
                raise GarageError(f"{along.at} is outside the motion's {lo:g}..{hi:g}", where + ".at")


def moves_ego(case) -> bool:
    """Whether the scenario's motion drives the ego (then its frames have times and a late verdict)."""
    return str(case.motion.actor) == EGO


def frame_times(values: list[float], speed_kmh: float) -> list[float]:
    """Seconds since the first frame, for the ego's motion values (metres along its path) at `speed_kmh`."""
    v = speed_kmh / 3.6
    return [abs(x - values[0]) / v if v > 0 else 0.0 for x in values]


def along_value(along, t: float, t_at: float, frame: int = 0) -> float:
    """An along-moving actor's value of its `key` at time t (frame `frame`): its listed values, else from start
    towards end (or along its `path`) at its speed, from t_at on."""
    listed = along.values
    if listed:
        return float(listed[min(frame, len(listed) - 1)])
    if along.path:
        return along_placement(along, 0.0, t, t_at)[along.key]
    start, end = float(along.start), float(along.end)
    moved = travelled(along, t - t_at)
    return min(start + moved, end) if end >= start else max(start - moved, end)


def along_placement(along, yaw: float, t: float, t_at: float, frame: int = 0) -> dict:
    """The placement values an along-moving actor (placed with yaw `yaw`) takes at time t: its `key`'s value; or,
    with a `path` of [distance, offset] points, both, and its yaw turned as each leg turns from the first."""
    if not along.path or along.values:
        return {along.key: along_value(along, t, t_at, frame)}
    points = [(float(d), float(o)) for d, o in along.path]
    moved = travelled(along, t - t_at)
    legs = list(zip(points, points[1:]))
    first = _leg_heading(*legs[0])
    for (d0, o0), (d1, o1) in legs:
        length = math.hypot(d1 - d0, o1 - o0)
        if moved <= length or (d1, o1) == points[-1]:
            k = min(moved / length, 1.0) if length > 0 else 1.0
            turn = _leg_heading((d0, o0), (d1, o1)) - first
            return {"distance": round(d0 + k * (d1 - d0), 6), "offset": round(o0 + k * (o1 - o0), 6),
                    "yaw": round(float(yaw) + turn, 6)}
        moved -= length
    raise AssertionError("unreachable: the last leg returns")


def _leg_heading(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Degrees of a leg of [distance, offset] points, from the path's heading (distance counts back along it,
    offset to its left)."""
    return math.degrees(math.atan2(b[1] - a[1], -(b[0] - a[0])))


def one_shot(n: int, frames: int | None) -> set[int]:
    """The frames of an n-frame trajectory that a K-frame scenario keeps (`case.frames`): K evenly spaced from
    the first to the last (the first alone for K=1); all of them for None or K >= n."""
    if frames is None or int(frames) >= n:
        return set(range(n))
    if int(frames) == 1:
        return {0}
    return {int(k) for k in np.round(np.linspace(0, n - 1, int(frames)))}


def steps(start: float, end: float, step: float) -> list[float]:
    """start, start +- step, ... up to end inclusive (either direction)."""
    if step <= 0:
        raise GarageError(f"step must be positive, got {step}", "case.motion.step")
    n = int(math.floor(abs(end - start) / step + 1e-9))
    sign = 1.0 if end >= start else -1.0
    return [round(start + sign * k * step, 6) for k in range(n + 1)]


def variants(case, actors: dict, colours: list[str]) -> tuple[list[Variant], dict]:
    """The variants to run, and the actors with palette-coloured ones copied per colour."""
    palette = [n for n, a in actors.items() if a.colour == PALETTE]
    if len(palette) > 1:
        raise GarageError(f"only one actor may take the palette's colours (have {', '.join(palette)})",
                          "case.actors")
    if palette:
        if case.variants:
            raise GarageError(f"actor {palette[0]!r} takes one variant per palette colour; give no variants",
                              "case.variants")
        name = palette[0]
        copies = {f"{name}_{c}": replace(actors[name], colour=c) for c in colours}
        rest = [n for n in actors if n not in (EGO, name)]
        out = [Variant(c, [f"{name}_{c}", *rest], f"{name}_{c}", {}) for c in colours]
        kept = {n: a for n, a in actors.items() if n != name}
        return out, {**kept, **copies}
    default_target = case.target or next((n for n, a in actors.items() if a.role == "target"), "")
    listed = case.variants or [VariantConf()]
    out = []
    for k, v in enumerate(listed):
        show = list(v.show or [n for n in actors if n != EGO])
        target = v.target or default_target
        if not target:
            raise GarageError("no target: give one actor role target, or name it in `target`", f"case.variants.{k}")
        for name in [*show, target]:
            if name not in actors:
                raise GarageError(f"no actor {name!r} (have {', '.join(actors)})", f"case.variants.{k}")
        if target not in show:
            raise GarageError(f"the target {target!r} is not among the shown actors", f"case.variants.{k}.target")
        label = v.label or ",".join(show)
        out.append(Variant(label, show, target, dict(v.set or {})))
    return out, actors


def frame_values(case, actor, site: Site, length: float, bays: dict) -> list[float]:
    """The motion's values: listed, or start..end by step; a distance the actor's path has no room for is an
    error, or trimmed to the room with the actor's `clip: true`."""
    m = case.motion
    on_path = m.key == "distance" and actor.path and not actor.before and not actor.relative \
        and actor.align == "centre"
    if m.values or m.start is None or m.end is None:
        listed = [float(v) for v in m.values] if m.values else [float(getattr(actor, m.key))]
        if m.values and on_path and not actor.clip:  # (a value of the actor's own is checked where it stands)
            _check_room(site, actor, m.actor, length, [("values", v) for v in listed])
        return listed
    start, end = float(m.start), float(m.end)
    if on_path:
        lo, hi = site_path(site, actor.path, f"case.actors.{m.actor}.path").room(length)
        if not actor.clip:
            _check_room(site, actor, m.actor, length, [("start", start), ("end", end)])
        start, end = (min(start, hi), max(end, lo)) if start >= end else (max(start, lo), min(end, hi))
        if (start < end) != (float(m.start) < float(m.end)) and start != end:
            raise GarageError(f"the path {actor.path!r} leaves {lo:.1f}..{hi:.1f} m; motion {m.start}..{m.end} "
                              "does not fit", "case.motion")
    return steps(start, end, float(m.step))


def _check_room(site: Site, actor, name: str, length: float, values: list[tuple[str, float]]) -> None:
    """The motion's distances fit the room the actor's path leaves; else GarageError naming the motion key."""
    path = site_path(site, actor.path, f"case.actors.{name}.path")
    lo, hi = path.room(length)
    for key, value in values:
        if not lo - 1e-9 <= value <= hi + 1e-9:
            raise no_room(path, actor.path, f"case.actors.{name}", f"{value:g} m", length, f"case.motion.{key}")


def level_file(job: SceneSpec, group: str) -> str:
    """The YAML file the group's values came from, for error messages: a scenario file of the command's
    (`--config-dir SUITE +scenario=NAME`, a `# @package _global_` file that sets the group's keys: an exported
    scenario) when one set them, else the group's level (named as its `name`); else `group=NAME`."""
    from garage_exp.core.paths import PROJECT_ROOT

    # the command's config sources as the job read them (SceneSpec: the scene builder reads no Hydra state)
    dirs, choices = list(job.config_dirs), dict(job.choices)
    folders = [*dirs, str(PROJECT_ROOT / "conf")]
    setting = [path for other, level in choices.items() if other != group and level
               for path in [_file_of(folders, other, str(level))] if path and _sets(path, group)]
    if setting:  # the last one in the defaults list wins, as its values do
        return str(setting[-1])
    return str(_file_of(folders, group, str(getattr(job, group).name)) or f"{group}={getattr(job, group).name}")


def _file_of(folders: list[str], group: str, level: str):
    from pathlib import Path

    return next((p for p in (Path(f) / group / f"{level}.yaml" for f in folders) if p.is_file()), None)


def _sets(path, group: str) -> bool:
    """Whether a global-package YAML file sets keys of `group` (an exported scenario sets `case`)."""
    import yaml

    try:
        text = path.read_text()
        data = yaml.safe_load(text) if "@package _global_" in text else None
    except (OSError, yaml.YAMLError):
        return False
    return isinstance(data, dict) and isinstance(data.get(group), dict)


def make_case(job: SceneSpec, classified: Classified, library, rng: np.random.Generator) -> CaseSetup:
    """The scenario's shot list, replicate after replicate (`replicates`); an error in the scenario or the
    arrangement names its file and key path."""
    try:
        setup = build_hosted(job, classified, library, rng)
        chosen = partial(build_case, site_index=setup.site_index)  # every replicate at replicate 0's site
        for k in range(1, int(job.replicates)):
            setup = merge(setup, build_replicate(chosen, job, classified, library, k), k)
        return setup
    except GarageError as exc:
        group = (exc.where or "").split(".")[0]
        if group in ("case", "occluder"):
            raise exc.again(str(exc), level_file(job, group)) from None
        raise


def site_order(job: SceneSpec, classified: Classified) -> list[int | None]:
    """The sites to try the case at, in turn: [None] (the kind's first, as the research's cases stand, with no
    other tried) without `case.site_index` and `case.site_draw`; else the one they pick, then each later site of
    the kind in order, wrapping round to the first, so that any index or draw gives a scenario when any site of
    the plan hosts it."""
    case = job.case
    index, draw = case.site_index, case.site_draw
    if index is None and draw is None:
        return [None]
    count = site_count(case.site, classified, job.garage)
    first = pick(count, index, draw, str(case.site), classified.plan.name)
    return [(first + k) % count for k in range(count)]


def build_hosted(job: SceneSpec, classified: Classified, library, rng: np.random.Generator) -> CaseSetup:
    """Replicate 0 of the case at the first site of `site_order` that hosts it (where its actors, path lengths
    and bays fit); every try starts from the same state of `rng`, so a site reached by skipping is built as if
    picked directly. When none hosts it, the picked site's own refusal is raised."""
    order = site_order(job, classified)
    state = rng.bit_generator.state
    refused = None
    for index in order:
        rng.bit_generator.state = state
        try:
            setup = build_case(job, classified, library, rng, site_index=index)
        except GarageError as exc:
            if len(order) == 1:
                raise
            refused = refused or exc
            log.info("case.site_index %s: the site does not host the case (%s); trying the next", index, exc)
            continue
        setup.site_index = index
        return setup
    raise refused


def build_case(job: SceneSpec, classified: Classified, library, rng: np.random.Generator, adjust=None,
               site_index: int | None = None) -> CaseSetup:
    """One replicate of the case at the site `site_index` of its kind (None: the first).
    `adjust(actors, targets)`: a replicate's variation of the actors' values."""
    case = job.case
    site = find_site(case.site, classified, job.garage, index=site_index)
    conf = actor_confs(case.actors, "case.actors")
    if EGO not in conf or conf[EGO].role != "ego":
        raise GarageError("a scenario needs an actor named 'ego' with role ego", "case.actors")
    bays = {str(k): str(v) for k, v in (case.bays or {}).items()}
    if case.motion.actor and case.motion.actor not in conf and case.motion.actor != "target":
        raise GarageError(f"no actor {case.motion.actor!r} to move (have {', '.join(conf)})", "case.motion.actor")
    _check_motion(case)
    runs, conf = variants(case, conf, list(job.palette.target_colours))
    if adjust is not None:
        conf = adjust(conf, {v.target for v in runs})
    # Actors are made in order of first use (the ego first): model draws from rng follow the scenario's order.
    made: dict[str, kinds.Made] = {}
    for name in dict.fromkeys([EGO] + [n for v in runs for n in v.show]):
        source = name if name in case.actors else name.rpartition("_")[0]  # palette copies: the original
        made[name] = kinds.make(name, conf[name], job, library, site, bays, rng, f"case.actors.{source}")

    shots: list[Shot] = []
    for variant in runs:
        actors = {n: conf[n] for n in [EGO, *variant.show]}
        for key, value in variant.set.items():
            name, _, attr = str(key).partition(".")
            if name not in actors or attr not in PLACEMENT:
                raise GarageError(f"variant {variant.label!r} sets {key!r}: a variant sets an actor's placement "
                                  f"({', '.join(PLACEMENT)}); another kind or model is another actor",
                                  "case.variants")
            actors[name] = replace(actors[name], **{attr: value})
        mover = next((n for n in actors if n == case.motion.actor or made[n].source == f"case.actors."
                      f"{case.motion.actor}"), None)
        if mover is None and case.motion.actor == "target":  # no actor named so: each variant's target
            mover = variant.target
        values = (frame_values(case, actors[mover], site, _longest(made, made[mover].source), bays) if mover
                  else [float("nan")])
        times = frame_times(values, float(job.ego_speed)) if mover == EGO else [0.0] * len(values)
        def time_at(x: float) -> float:
            return frame_times([values[0], x], float(job.ego_speed))[1]

        alongs = [(n, a, start_time(a, time_at)) for n, a in (case.motion.along or {}).items() if n in actors]
        kept = one_shot(len(values), case.frames)
        for frame, (value, time) in enumerate(zip(values, times)):
            if frame not in kept:  # a one-shot scenario: the trajectory's frames, K of them
                continue
            placed = dict(actors)
            if mover:
                placed[mover] = replace(actors[mover], **{case.motion.key: value})
            for name, along, t_at in alongs:
                placed[name] = replace(placed[name], **along_placement(along, actors[name].yaw, time, t_at, frame))
            try:
                poses = resolve(placed, made, site, bays)
            except GarageError as exc:
                raise along_error(exc, alongs, placed, made, frame) from None
            check_overlaps(poses, made, variant.label, value,
                           room=lambda pair, placed=placed: gap_room(placed, made, site, bays, pair))
            shot_poses = {n: poses.get(n) for n in made if n != EGO}
            shots.append(Shot(len(shots), variant.label, value, poses[EGO], shot_poses, variant.target,
                              time=round(time, 6)))
    free = [site_bay(site, ref, bays, "case.keep_free").bay for ref in case.keep_free]
    taken = {b for m in made.values() for b in m.bays} | {(b.i, b.j, b.index) for b in free}
    arrange(job, classified, library, site, bays, rng, made, shots, taken)
    for name, m in made.items():
        first = next((s.poses.get(name) for s in shots if s.poses.get(name)), None)
        m.entity.pose = shots[0].ego if name == EGO else first or m.entity.pose
    used = sorted({b for m in made.values() for b in m.bays} | taken)
    return CaseSetup([m.entity for m in made.values()], shots, occluder=site.pillar, used_bays=used,
                     position_label=case.position_label or "position (m)")


def along_error(exc: GarageError, alongs: list, placed: dict, made: dict, frame: int) -> GarageError:
    """A placement refused for a value an along-moving actor reached (a car pulled out past its whole length):
    named by the co-motion's key that asked for it (its `start` when the first frame fails, else its `end`, or
    its `values`); any other refusal as it was."""
    for name, along, _ in alongs:
        keys = ("distance", "offset") if along.path else (along.key,)
        for key in keys:
            if exc.where == f"{made[name].source}.{key}":
                value = float(getattr(placed[name], key))
                which = "values" if along.values else "path" if along.path else \
                    "start" if frame == 0 else "end"
                reason = str(exc)[len(exc.where) + 2:]
                return GarageError(f"{name}'s {key} reaches {value:g} (frame {frame}): {reason}",
                                   f"case.motion.along.{name}.{which}")
    return exc


def gap_room(actors: dict, made: dict, site: Site, bays: dict, pair: tuple[str, str]) -> str:
    """For an overlap message: how far a person between two bays (one of `pair`) may stand off the gap's middle
    in this frame, by the one rule of what may stand (place.sweep_clash over offsets from the middle)."""
    for name in pair:
        a = actors[name]
        if not a.between:
            continue

        def fits(offset: float, name=name, a=a) -> bool:
            ends = [resolve({**actors, name: replace(a, offset=v)}, made, site, bays) for v in (0.0, offset)]
            return sweep_clash(ends, made, only={name}) is None

        lo, hi = farthest(fits, 0.0, -GAP_SEARCH), farthest(fits, 0.0, GAP_SEARCH)
        where = f"{made[name].source}.offset"
        if lo is None:
            return f"; {name} does not fit its gap here at any {where}"
        return f"; {where} fits {lo:g} to {hi:g} m here"
    return ""


def _longest(made: dict, source: str) -> float:
    """The longest of an actor's copies (the palette's colours): the room on a path fits them all."""
    return max(m.extent[0] for m in made.values() if m.source == source)


def resolve(actors: dict, made: dict, site: Site, bays: dict) -> dict[str, Pose]:
    """Every actor's pose in one frame; an actor placed relative to another follows it."""
    poses: dict[str, Pose] = {}
    axes: dict[str, tuple[float, float]] = {}
    tracks: dict[str, object] = {}  # the site path an actor stands on (an actor relative to another: the other's)

    def place(name: str, seen: tuple[str, ...] = ()) -> Pose:
        if name in poses:
            return poses[name]
        a, where = actors[name], made[name].source
        length = made[name].extent[0]
        if a.relative:
            if a.relative not in actors or a.relative in seen:
                raise GarageError(f"relative to {a.relative!r}: no such actor in this variant, or a cycle",
                                  where + ".relative")
            ref = place(a.relative, (*seen, name))
            axes[name] = axes[a.relative]
            pose = pose_relative(ref, axes[a.relative], a, (made[a.relative].extent, made[name].extent))
            tracks[name] = tracks.get(a.relative)
            if a.clip and tracks[name] is not None:  # trimmed to the room its path leaves, as on a path
                pose = clip_to(tracks[name], pose, length)
        elif a.path and a.before in actors:  # counted back from another actor (its projection on the path)
            if a.before in seen:
                raise GarageError(f"before {a.before!r} makes a cycle", where + ".before")
            path = tracks[name] = site_path(site, a.path, where + ".path")
            ref = place(a.before, (*seen, name))
            axes[name] = path.axis
            x, y = path.at_world(path.along(ref.x, ref.y) - float(a.distance))
            pose = Pose(x - a.offset * path.axis[1], y + a.offset * path.axis[0], 0.0,
                        (path.heading + float(a.yaw)) % 360.0)
        elif a.path:
            tracks[name] = site_path(site, a.path, where + ".path")
            axes[name] = tracks[name].axis
            pose = pose_on_path(site, a, length, bays, where)
        elif a.bay != "":
            sb = site_bay(site, a.bay, bays, where + ".bay")
            axes[name] = sb.facing
            pose = pose_in_bay(site, a, length, bays, where)
        elif a.between:
            axes[name] = site_bay(site, a.between[0], bays, where + ".between").facing
            pose = pose_between(site, a, bays, where)
        else:
            raise GarageError("no placement: give path, bay, between or relative", where)
        poses[name] = pose
        return pose

    for name in actors:
        place(name)
    return poses


def clip_to(path, pose: Pose, length: float) -> Pose:
    """The pose moved along its path into the room the path leaves an actor `length` long (room: its ends' margin)."""
    s = path.along(pose.x, pose.y) - path.along(*path.origin)  # in the path's own frame, as its room is
    lo, hi = room(path, length)
    shift = min(max(s, lo), hi) - s if lo <= hi else 0.0
    return Pose(pose.x + shift * path.axis[0], pose.y + shift * path.axis[1], pose.z, pose.yaw)


__all__ = ["EGO", "Shot", "CaseSetup", "check_case", "make_case", "steps"]
