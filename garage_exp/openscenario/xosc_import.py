"""`python -m garage_exp.scenario.import FILE.xosc`: an OpenSCENARIO file as a case YAML, for the subset a case
can say, with one line per element it leaves out.

Mapped: entities to our actors (a Vehicle by its garage_exp model, else by body from its category and the
vehicle library's size class for its size, a category the library cannot render refused; a Pedestrian to a
person of its height; a MiscObject to a box), each placed on the site's `lane` (`before:` the site's first bay,
`distance`, `offset`, `yaw`): where it starts; the ego's speed and route to the case's motion (the ego's
`distance`, from its start to its route's end); another actor's speed (or a timed polyline's), route or
trajectory and what starts it (the ego's travelled distance, the simulation time, the ego's time headway to an
entity, or a SynchronizeAction's arrival) to a co-motion (`case.motion.along`: `offset` across the lane or
`distance` along it, every vertex of a bent route as its `path`, `speed`, `accelerate`, `at` or `meet`). The case
then goes through the scenario's own checks (a target to score, `--target`) before it is written.

Where it stands: a file garage_exp wrote (its FileHeader says `garage_exp ... plan=NAME`) is in the plan's own
world frame; any other file is moved as a whole so that its ego starts on the site's lane, heading along it, with
its rearmost actor's back 0.5 m past the lane's start (`--margin`). An actor that then stands outside the
plan or in a wall needs a road the plan cannot place: one line naming the file and the element, exit 2, nothing
written; so is a file that is not XML or fails the ASAM schema.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import yaml

from garage_exp.assets.vehicles import SIZES_OF_KIND, size_class_for, size_class_of
from garage_exp.core import shell
from garage_exp.core.errors import GarageError
from garage_exp.openscenario.xosc_read import Read, read

STEP = 0.5  # m a frame of the ego's motion (the case's default)
SWEEP = 0.25  # m a frame of a static case's sweep (the pedestrian case's)
SHORT = 0.5  # m: an imported ego stops this far before a synchronised meeting (a collision test's impact)
OWN = "garage_exp "
# vehicleCategory -> the body (vehicle kind) the library draws it as; any other category is refused
BODIES = {"car": "car", "van": "van", "bus": "bus", "truck": "truck", "semitrailer": "truck", "trailer": "truck"}


def load_site(plan: str, site_name: str):
    from garage_exp.core.paths import PLANS_DIR, PROJECT_ROOT
    from garage_exp.core.plain import structured
    from garage_exp.scene.schema import GarageConf
    from garage_exp.plan import classify, load_plan
    from garage_exp.scenario.sites import find_site

    path = Path(plan) if Path(plan).suffix else PLANS_DIR / f"{plan}.yaml"
    if not path.is_file():
        raise GarageError(f"no plan {plan!r} (a shipped plan's name or a plan file)", "--plan")
    garage = structured(GarageConf, PROJECT_ROOT / "conf" / "garage" / "default.yaml")
    classified = classify(load_plan(path))
    site = find_site(site_name, classified, garage)
    if "lane" not in site.paths or not site.bays:
        raise GarageError(f"the site {site_name} has no path `lane` with bays (straight_run, lane_bays)", "--site")
    return classified, site


def ego_of(r: Read) -> str:
    by_role = [n for n, t in r.things.items() if t.properties.get("garage_exp.role") == "ego"]
    named = [n for n in r.things if n.lower() in ("ego", "hero", "egovehicle")]
    vehicles = [n for n, t in r.things.items() if t.type == "Vehicle"]
    found = (by_role or named or vehicles)
    if not found:
        raise GarageError("no vehicle to be the ego", f"{r.path}: Entities")
    return found[0]


def own(r: Read, key: str) -> str | None:
    """A value a file garage_exp wrote says in its description (`plan=research step=0.5 ...`); None for others."""
    if not r.description.startswith(OWN):
        return None
    words = dict(w.split("=", 1) for w in r.description.split() if "=" in w)
    return words.get(key)


def own_plan(r: Read) -> str | None:
    return own(r, "plan")


def _actor(r: Read, name: str, role: str, moving: bool, notes: list[str]) -> dict:
    t = r.things[name]
    p = t.properties
    length, width, height = t.extent
    if t.type == "Pedestrian":
        age = p.get("garage_exp.age") or ("child" if height < 1.4 else "adult")
        person = {"role": role, "kind": "person", "age": age,
                  "height": round(float(p.get("garage_exp.height") or height), 3),
                  "pose": p.get("garage_exp.pose") or ("walking" if moving else "standing")}
        person.update({k: p[f"garage_exp.{k}"] for k in ("gender", "build") if p.get(f"garage_exp.{k}")})
        return person
    if t.type == "MiscObject":
        return {"role": role, "kind": "box", "length": round(length, 3), "width": round(width, 3),
                "height": round(height, 3)}
    if p.get("garage_exp.model"):
        return {"role": role, "model": p["garage_exp.model"]}
    body = BODIES[t.category]  # (a category we cannot render is refused in `vehicles_we_render`)
    size = size_class_for(body, length, height)
    if size != size_class_of(length, height):
        notes.append(f"{name}: a {t.category} {length:g} m long, {height:g} m tall; the vehicle library's "
                     f"{body}s are {' or '.join(SIZES_OF_KIND[body])}: taken as {size}")
    return {"role": role, "size": size, "body": body}


def vehicles_we_render(r: Read) -> None:
    """Refuse a vehicle of a category the vehicle library has nothing like (a bicycle, a motorbike, a train): it
    would otherwise become a car."""
    for name, t in r.things.items():
        if t.type == "Vehicle" and not t.properties.get("garage_exp.model") and t.category not in BODIES:
            raise GarageError(f"{name} is a {t.category or 'vehicle of no category'}: the vehicle library renders "
                              f"{', '.join(sorted(set(BODIES.values())))} (vehicleCategory "
                              f"{', '.join(BODIES)})", f"{r.path}: {r.tree.getpath(t.element)}")


def to_case(r: Read, classified, site, name: str, margin: float, target: str | None = None
            ) -> tuple[dict, list[str]]:
    """The case (a dict for its YAML) and the lines saying what it took and what it left out."""
    lane = site.paths["lane"]
    ax, ay = lane.axis
    bay0 = site.bays[0].bay
    t0 = lane.along(bay0.x, bay0.y)
    ego = ego_of(r)
    vehicles_we_render(r)
    notes: list[str] = []
    transform = _identity if own_plan(r) else _onto_lane(r, ego, lane, margin)

    def place(x, y, h):
        x, y, h = transform(x, y, h)
        cell = classified.plan.cell_at(x, y)
        return x, y, h, cell

    placed = {}
    for n, start in r.start.items():
        x, y, h, cell = place(*start)
        if cell is None or classified.cell(*cell).kind == "obstacle":
            where = "outside the plan" if cell is None else f"in the wall cell {cell}"
            raise GarageError(f"needs a road the plan cannot place: {n} starts at ({x:.1f}, {y:.1f}) m, {where} "
                              f"(plan {classified.plan.name}, site {site.name})", f"{r.path}: {r.tree.getpath(r.things[n].element)}")
        placed[n] = (x, y, h)
    for n in r.things:
        if n not in placed:
            notes.append(f"left out entity {n!r}: the file never places it")

    def distance(x, y):
        return round(t0 - (x * ax + y * ay), 4)

    def offset(x, y):
        return round((x - lane.origin[0]) * -ay + (y - lane.origin[1]) * ax, 4)

    names = {n: ("ego" if n == ego else _key(n)) for n in placed}
    movers = {n for n in placed if any(m.speed != 0 for m in r.moves.get(n, []))}
    people = [n for n in placed if r.things[n].type == "Pedestrian" and n != ego]
    if target is not None and target not in placed:
        raise GarageError(f"--target {target}: no entity of that name the file places ({', '.join(placed)})",
                          str(r.path))
    target = target or next((n for n in placed if n == own(r, "target")), None) \
        or next((n for n in placed if r.things[n].properties.get("garage_exp.role") == "target"), None) \
        or (people[0] if people else next((n for n in placed if n != ego and n in movers), None))
    actors = {}
    for n, (x, y, h) in placed.items():
        role = r.things[n].properties.get("garage_exp.role") or (
            "ego" if n == ego else "target" if n == target else "moving" if n in movers else "parked")
        actor = _actor(r, n, role, n in movers, notes)
        actor.update({"path": "lane", "before": "ref", "distance": distance(x, y), "offset": offset(x, y),
                      "yaw": round((math.degrees(h) - lane.heading + 180) % 360 - 180, 4)})
        actors[names[n]] = actor
    case = {"name": name, "site": site.name, "position_label": "ego distance before the reference bay (m)",
            "bays": {"ref": "0"}, "actors": actors}
    ego_speed = next((abs(m.speed) for m in r.moves.get(ego, []) if m.speed != 0), 0.0)  # < 0: reversing
    step = float(own(r, "step") or STEP)
    motion: dict = {}
    if ego_speed > 0:
        key, value = "distance", distance
        d0 = actors["ego"]["distance"]
        if r.routes.get(ego):
            ex, ey, _ = transform(*r.routes[ego][-1], 0.0)
            if abs(offset(ex, ey) - actors["ego"]["offset"]) > abs(distance(ex, ey) - d0):
                key, value = "offset", offset  # a route across the site's lane (another lane of the plan)
                d0 = actors["ego"]["offset"]
            d1 = value(ex, ey)
            if key == "distance" and not own_plan(r):  # (a file of ours drove a lane of this plan)
                lo, hi = sorted(distance(*lane.point(s)) for s in lane.room(r.things[ego].extent[0]))
                if not lo <= d1 <= hi:  # a test track's run-out is longer than a garage's lane
                    notes.append(f"ego: its route runs {abs(d1 - d0):.1f} m, past the lane: cut at the lane's end")
                    d1 = min(max(d1, lo), hi)
        elif target:
            d1 = actors[names[target]]["distance"] + 3.0
            notes.append("ego: no route; it drives to 3 m before the target's distance")
        else:
            d1 = d0
        motion = {"actor": "ego", "key": key, "start": d0, "end": round(d1, 4), "step": step}
        notes.append(f"ego speed {ego_speed * 3.6:.4g} km/h: run the case with ego.speed={ego_speed * 3.6:.4g}")
    along = {}
    for n in sorted(movers - {ego}, key=list(placed).index):
        spec = _along(r, n, placed[n], transform, distance, offset, motion, ego, ego_speed, notes, placed)
        if spec is None:
            continue
        if motion:
            along[names[n]] = spec
        else:  # a static ego: this actor's move is the case's motion, frame by frame
            sweep = float(own(r, "step") or SWEEP)
            motion = {"actor": names[n], "key": spec["key"], "start": spec["start"], "end": spec["end"],
                      "step": sweep}
            notes.append(f"{n}: the ego stands: its move is swept {sweep:g} m a frame (its speed is not a case's)")
    if along:
        motion["along"] = along
        meets = [spec["meet"] for spec in along.values() if "meet" in spec]
        # a protocol's impact: the frames stop short of it (a file of ours ends its ego's route at the last frame)
        if meets and motion.get("actor") == "ego" and not own_plan(r):
            d0, d1 = motion["start"], motion["end"]
            short = round(max(d1, min(meets) + SHORT) if d1 < d0 else min(d1, max(meets) - SHORT), 4)
            if short != d1:
                notes.append(f"ego: stops {SHORT:g} m short of the synchronised meeting (the file's impact)")
                motion["end"] = short
    if motion:
        case["motion"] = motion
    if target:
        case["target"] = names[target]
    renamed = [f"{n} -> {k}" for n, k in names.items() if n != k]
    if renamed:
        notes.append("actors renamed: " + ", ".join(renamed))
    return case, notes


def check_runs(case: dict, r: Read) -> None:
    """What a job asks of the case before it has a plan (the scenario's own checks: its schema, its motion, each
    variant's target), so that a case that would fail as a job is refused here, naming the file."""
    from garage_exp.core.plain import as_object, structured
    from garage_exp.scenario.schema import CaseConf
    from garage_exp.scenario.build import _check_motion, variants

    try:
        conf = as_object(structured(CaseConf, case))  # typed as a job's scene builder is handed it
        _check_motion(conf)
        variants(conf, dict(conf.actors), [])
    except GarageError as exc:
        hint = " (name one with --target ENTITY)" if "no target" in str(exc) else ""
        raise GarageError(f"the case would not run: {exc}{hint}", str(r.path)) from None


def _along(r: Read, n: str, start, transform, distance, offset, motion, ego, ego_speed, notes, placed: dict
           ) -> dict | None:
    """A moving actor's co-motion; its `at` and `meet` are values of the ego's motion (`motion`)."""
    ego_value = offset if motion.get("key") == "offset" else distance
    d0 = motion.get("start", 0.0)
    ahead = -1.0 if motion.get("end", d0) < d0 else 1.0  # which way the ego's value runs as it drives
    # a synchronisation says the walk (a speed before it only gets it under way: one already moving at the start)
    m = next((m for m in r.moves[n] if m.meet is not None), None) or next(m for m in r.moves[n] if m.speed != 0)
    route = r.routes.get(n)
    if not route or len(route) < 2:
        notes.append(f"{n}: a speed without a route or trajectory: left standing")
        return None
    ex, ey, _ = transform(*route[-1], 0.0)
    if m.meet is not None:  # arriving at its target point as the master reaches its own
        ex, ey, _ = transform(*m.meet[2], 0.0)
    sx, sy = start[0], start[1]
    across = abs(offset(ex, ey) - offset(sx, sy)) >= abs(distance(ex, ey) - distance(sx, sy))
    key, get = ("offset", offset) if across else ("distance", distance)
    spec = {"key": key, "start": get(sx, sy), "end": get(ex, ey), "speed": round(abs(m.speed), 4)}
    length = math.hypot(ex - sx, ey - sy)
    if m.meet is None:  # every vertex of its route or polyline, not only the last
        points = [(sx, sy)]
        for x, y in route:
            x, y, _ = transform(x, y, 0.0)
            if math.hypot(x - points[-1][0], y - points[-1][1]) > 0.01:
                points.append((x, y))
        legs = [[distance(x, y), offset(x, y)] for x, y in points]
        bent = len(legs) > 2 or (len(legs) == 2 and min(abs(legs[1][0] - legs[0][0]),
                                                         abs(legs[1][1] - legs[0][1])) > 0.01)
        if bent:  # more than one leg, or one that is not straight along or across the lane
            spec["path"] = legs
            spec["start"], spec["end"] = legs[0][0 if key == "distance" else 1], legs[-1][0 if key == "distance" else 1]
            notes.append(f"{n}: its route of {len(legs) - 1} leg(s) kept as a path of [distance, offset] points")
    if m.rate > 0:
        spec["accelerate"] = round(m.speed * m.speed / (2 * m.rate), 4)
    if m.meet is not None:
        master, (mx, my), _, steady = m.meet
        if master != ego:
            notes.append(f"{n}: synchronised with {master!r}, not the ego: left standing")
            return None
        cx = r.things[ego].centre_x
        h = r.start[ego][2]
        mx, my, _ = transform(mx + cx * math.cos(h), my + cx * math.sin(h), 0.0)
        spec["meet"] = ego_value(mx, my)
        if steady is not None:
            spec["accelerate"] = round(max(0.0, length - steady), 4)
        notes.append(f"{n}: SynchronizeAction with the ego -> meet {spec['meet']:g} (arrives at its target then stops)")
    elif m.trigger[0] == "travel" and m.by == ego:
        spec["at"] = round(d0 + ahead * m.trigger[1], 4)
    elif m.trigger[0] == "time" and m.trigger[1] > 0:
        spec["at"] = round(d0 + ahead * m.trigger[1] * ego_speed, 4)
    elif m.trigger[0] == "headway" and m.by == ego and motion.get("key") == "distance":
        # the ego's value when it is that many seconds (at its speed) from the other entity: its front that far
        # before the other's back (freespace), else its centre before the other's
        _, seconds, of, freespace = m.trigger
        ends = (r.things[ego].extent[0] + r.things[of].extent[0]) / 2 if freespace and of in r.things else 0.0
        at = round(distance(*placed[of][:2]) - ahead * (seconds * ego_speed + ends), 4) if of in placed else d0
        if (at - d0) * ahead > 0:
            spec["at"] = at
            notes.append(f"{n}: sets off when the ego is {seconds:g} s from {of!r} -> at {at:g}")
        else:
            notes.append(f"{n}: sets off when the ego is {seconds:g} s from {of!r}, as it is from the first frame")
    elif m.trigger[0] == "travel":
        notes.append(f"{n}: started by {m.by!r}'s travel, not the ego's: taken as starting at once")
    return spec


def _identity(x, y, h):
    return x, y, h


def _onto_lane(r: Read, ego: str, lane, margin: float):
    """The rigid move that puts the ego's start on the lane's centre line, heading along it, with the rearmost
    actor's back (the ego's, or a person's behind a reversing ego) `margin` m past the lane's start."""
    x0, y0, h0 = r.start[ego]
    c0, s0 = math.cos(h0), math.sin(h0)
    rear = min((x - x0) * c0 + (y - y0) * s0 - max(r.things[n].extent[:2]) / 2 for n, (x, y, _) in r.start.items())
    tx, ty = lane.point(lane.lo + margin - rear)
    turn = math.radians(lane.heading) - h0
    c, s = math.cos(turn), math.sin(turn)

    def move(x, y, h):
        dx, dy = x - x0, y - y0
        return tx + c * dx - s * dy, ty + s * dx + c * dy, h + turn

    return move


def _key(name: str) -> str:
    out = "".join(ch if ch.isalnum() else "_" for ch in name).strip("_").lower() or "actor"
    return out if not out[0].isdigit() else f"a_{out}"


COMMAND = shell.Command("garage_exp.scenario.import")


def run(args: argparse.Namespace) -> int:
    params = {}
    for item in args.param:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise GarageError(f"{item!r} is not NAME=VALUE", "--param")
        params[key] = value
    r = read(args.xosc, params)
    name = _key(args.name or args.xosc.stem)
    classified, site = load_site(args.plan or own_plan(r) or "research", args.site)
    case, notes = to_case(r, classified, site, name, args.margin, args.target)
    check_runs(case, r)
    out = args.output or Path("case") / f"{name}.yaml"
    lines = [*r.left_out, *notes]
    head = [f"# Imported from {args.xosc} by python -m garage_exp.scenario.import"
            + (f" ({', '.join(f'{k}={v}' for k, v in params.items())})" if params else ""),
            *(f"# {line}" for line in lines)]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(head) + "\n" + yaml.safe_dump(case, sort_keys=False))
    for line in lines:
        print(line)
    print(f"garage_exp.scenario.import: wrote {out} ({len(case['actors'])} actors; {len(r.left_out)} element(s) "
          "left out)")
    return 0


def main(argv: list[str] | None = None) -> int:
    """The command in the one shell (garage_exp.core.shell): bad input one line and 2, Ctrl-C 130, SIGTERM 143."""
    ap = argparse.ArgumentParser(prog="python -m garage_exp.scenario.import", description=__doc__.splitlines()[0])
    ap.add_argument("xosc", type=Path, help="an OpenSCENARIO 1.0-1.3 scenario file")
    ap.add_argument("-o", "--output", type=Path, help="the case YAML to write (default: case/NAME.yaml here, "
                    "so that `python -m garage_exp --config-dir . case=NAME` runs it)")
    ap.add_argument("--name", help="the case's name (default: the file's stem)")
    ap.add_argument("--plan", help="a shipped plan's name or a plan file (default: the file's own, else research)")
    ap.add_argument("--site", default="straight_run", help="a site with a lane and bays (default straight_run)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="set one of the file's parameters (repeatable), e.g. Ego_speed_kph=10")
    ap.add_argument("--target", metavar="ENTITY", help="the entity the case is scored on (default: the file's "
                    "garage_exp.role target, else its first pedestrian, else its first moving actor)")
    ap.add_argument("--margin", type=float, default=0.5,
                    help="a foreign file is placed with its rearmost actor's back this far past the lane's start (m)")
    return COMMAND.run_args(ap, run, argv)


def cli() -> None:
    """The command line's entry (`python -m garage_exp.scenario.import`): main's exit code."""
    sys.exit(main())
