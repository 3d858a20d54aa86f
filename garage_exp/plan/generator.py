"""The seeded garage generator (`plan=generated`): one valid plan (S, R, C) per seed, from ranges a user sets.

A draw picks a layout family and its sizes, then lays the plan out on a grid of bands:

- rows, north to south: a row of bays along the north wall (or a bare wall), then per aisle an east-west lane
  with an island of two back-to-back bay rows before the next aisle, then bays along the south wall;
- columns, west to east: bays along the west wall, the family's north-south cross lanes with runs of bay cells
  ("spans", pillar to pillar) between them, bays along the east wall.

Families differ in their cross lanes (docs/plans.md has a map of each):

- `loop`: cross lanes at both ends (the research's ring when there are two aisles, a ladder with more);
- `comb`: one cross lane at the west end, the aisles end blind at the east;
- `grid`: cross lanes at both ends and in the middle (crossroads where the middle one meets inner aisles);
- `spine`: one cross lane in the middle, the aisles end blind at both walls (no corners: case 1 has no site).

Then stair and lift cores replace island cells, one or two perimeter bays facing a lane become the ramps
(entrance, exit), and a bay left without a lane of its own becomes a wall (obstacle). Dimensions follow the
German model garage ordinance (MGarVO section 4, ../shared/FACTS.md "Physical ranges"): bays at least 5.0 m
deep and 2.30 m wide, 2.40 m clear beside a pillar; lanes at least 6.50 / 6.00 / 5.50 m behind 2.30 / 2.40 /
2.50 m bays; at least 2.0 m clear under the beams. A cell along an aisle holds `bays_per_span` bays: its width is
what keeps its end bays clear of the pillars at its corners. The draw also carries the garage values the plan was
sized for (pillar size, bay width, ceiling height), which a job hands on to `garage.*` (run/preflight.py).

A draw takes about a millisecond (no classification); it is pure Python and numpy, memoised per process.
"""

from __future__ import annotations

import hashlib
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE
from garage_exp.plan.load import plan_from_lists
from garage_exp.plan.model import ENTRANCE, EXIT, LANE, OBSTACLE, PARKING, Plan

WHERE = "plan.generator"
# Layout families, west to east: | a north-south cross lane, B a block of spans between cross lanes, b a block
# that ends blind (an aisle's dead end).
FAMILIES = {"loop": "|B|", "comb": "|b", "grid": "|B|B|", "spine": "b|b"}

# The ordinance (MGarVO section 4): a bay >= 2.30 m wide, 2.40 m with a wall or pillar on one side, 2.50 m on both.
BAY_MIN, BAY_ONE_SIDE, BAY_BOTH_SIDES = 2.30, 2.40, 2.50
# The narrowest lane behind 90-degree bays of a width (interpolated between the ordinance's three points).
LANE_BY_BAY = ((2.30, 2.40, 2.50), (6.50, 6.00, 5.50))
BEAM_DEPTH = 0.25  # scene/bays.py's downstand beams: the clear height is the ceiling's less this
CLEAR_HEIGHT = 2.0

# key: (kind, lo, hi, unit): what a setting may be. kind int/float: a value or a [lo, hi] range within lo-hi;
# "share": one probability; "family": a name or a list of names.
LIMITS: dict[str, tuple[str, float, float, str]] = {
    "family": ("family", 0, 0, ""),
    "aisles": ("int", 1, 8, ""),
    "spans": ("int", 1, 12, ""),
    "bays_per_span": ("int", 1, 4, ""),
    "bay_width": ("float", BAY_MIN, 3.0, " m"),
    "bay_depth": ("float", 5.0, 6.0, " m"),
    "lane_width": ("float", 5.5, 8.0, " m"),
    "pillar_size": ("float", 0.3, 1.0, " m"),
    "ceiling_height": ("float", CLEAR_HEIGHT + BEAM_DEPTH, 4.0, " m"),
    "ramps": ("int", 1, 2, ""),
    "cores": ("int", 0, 6, ""),
    "wall_bays": ("share", 0.0, 1.0, ""),
}
WHY = {"bay_width": "MGarVO: bays at least 2.30 m wide", "bay_depth": "MGarVO: bays at least 5.0 m long",
       "lane_width": "MGarVO: lanes at least 5.50 m", "ceiling_height": "MGarVO: 2.0 m clear under 0.25 m beams"}


@dataclass(frozen=True)
class GeneratorSettings:
    """Checked generator settings: ranges as (lo, hi), families as a tuple (hashable: draws are memoised)."""

    family: tuple[str, ...]
    aisles: tuple[int, int]
    spans: tuple[int, int]
    bays_per_span: tuple[int, int]
    bay_width: tuple[float, float]
    bay_depth: tuple[float, float]
    lane_width: tuple[float, float]
    pillar_size: tuple[float, float]
    ceiling_height: tuple[float, float] | None
    ramps: tuple[int, int]
    cores: tuple[int, int]
    wall_bays: float


@dataclass(frozen=True)
class Draw:
    """One generated garage: the plan (its `garage` holds the values it was sized for) and what was drawn."""

    plan: Plan
    seed: int
    family: str
    params: tuple[tuple[str, Any], ...]  # (name, value) of every drawn parameter, for the YAML's header

    @property
    def garage(self) -> dict[str, float]:
        return dict(self.plan.garage)


def lane_minimum(bay_width: float) -> float:
    """The ordinance's narrowest lane behind 90-degree bays `bay_width` wide."""
    return float(np.interp(bay_width, *LANE_BY_BAY))


def _range(key: str, value: Any, kind: str, lo: float, hi: float, unit: str) -> tuple:
    where = f"{WHERE}.{key}"
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if not 1 <= len(values) <= 2:
        raise GarageError(f"{_show(value)} is not a value or a range [lo, hi]", where)
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (kind == "int" and not float(v).is_integer()):
            what = "an integer" if kind == "int" else "a number"
            raise GarageError(f"{_show(v)} is not {what}", where)
        if not (math.isfinite(v) and lo <= v <= hi):
            why = f" ({WHY[key]})" if key in WHY else ""
            raise GarageError(f"{v:g}{unit} is outside {lo:g}-{hi:g}{unit}{why}", where)
        out.append(int(v) if kind == "int" else float(v))
    if out[0] > out[-1]:
        raise GarageError(f"range [{out[0]:g}, {out[-1]:g}] runs backwards (lo > hi)", where)
    return out[0], out[-1]


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def generator_settings(node: Any) -> GeneratorSettings:
    """The `plan.generator` node (a mapping) checked: GarageError naming `plan.generator.KEY` on the first bad
    setting (an unknown key, a non-number, a value outside its physical range, a lane too narrow for the bays)."""
    from garage_exp.core.errors import did_you_mean
    from garage_exp.plan.schema import PlanGeneratorConf

    if not hasattr(node, "keys"):
        raise GarageError(f"expected a mapping of generator settings, got {_show(node)}", WHERE)
    given = {str(k): node[k] for k in node.keys()}
    for key in given:
        if key not in LIMITS:
            raise GarageError(f"unknown setting {key!r}{did_you_mean(key, LIMITS)}", f"{WHERE}.{key}")
    defaults = PlanGeneratorConf()
    values: dict[str, Any] = {}
    for key, (kind, lo, hi, unit) in LIMITS.items():
        value = given.get(key, getattr(defaults, key))
        where = f"{WHERE}.{key}"
        if kind == "family":
            names = list(value) if isinstance(value, (list, tuple)) else [value]
            if not names or any(str(n) not in FAMILIES for n in names) or any(not isinstance(n, str) for n in names):
                bad = next((n for n in names if str(n) not in FAMILIES), names)
                raise GarageError(f"unknown layout family {_show(bad)} (have: {', '.join(FAMILIES)})", where)
            values[key] = tuple(dict.fromkeys(names))
        elif kind == "share":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
                raise GarageError(f"{_show(value)} is not a probability in 0-1", where)
            values[key] = float(value)
        elif value is None and key == "ceiling_height":
            values[key] = None  # the garage group's own ceiling
        else:
            values[key] = _range(key, value, kind, lo, hi, unit)
    gen = GeneratorSettings(**values)
    # The widest lane allowed must be wide enough behind the narrowest bays allowed.
    need = lane_minimum(gen.bay_width[0])
    if gen.lane_width[1] < need - 1e-9:
        raise GarageError(f"lanes up to {gen.lane_width[1]:g} m are narrower than the {need:.2f} m the ordinance "
                          f"wants behind {gen.bay_width[0]:g} m bays (MGarVO section 4): widen lane_width or raise "
                          "bay_width", f"{WHERE}.lane_width")
    return gen


def check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise GarageError(f"{_show(seed)} is not a seed (an integer >= 0)", "plan.seed")
    return int(seed)


def _uniform(rng: np.random.Generator, r: tuple[float, float]) -> float:
    return round(float(rng.uniform(r[0], r[1])), 2) if r[1] > r[0] else r[0]


def _integer(rng: np.random.Generator, r: tuple[int, int]) -> int:
    return int(rng.integers(r[0], r[1] + 1)) if r[1] > r[0] else r[0]


def _ceil_cm(value: float) -> float:
    return math.ceil(value * 100 - 1e-6) / 100


def draw(gen: GeneratorSettings, seed: int) -> Draw:
    """The garage of `seed` (the same seed and settings give the same plan, in any process)."""
    return _draw_cached(gen, check_seed(seed))


@STATE.memo("process", maxsize=64)
def _draw_cached(gen: GeneratorSettings, seed: int) -> Draw:
    rng = np.random.default_rng(seed)
    family = gen.family[int(rng.integers(len(gen.family)))] if len(gen.family) > 1 else gen.family[0]
    template = FAMILIES[family]
    aisles, spans, per_span = _integer(rng, gen.aisles), _integer(rng, gen.spans), _integer(rng, gen.bays_per_span)
    bay, depth, pillar = _uniform(rng, gen.bay_width), _uniform(rng, gen.bay_depth), _uniform(rng, gen.pillar_size)
    ceiling = None if gen.ceiling_height is None else _uniform(rng, gen.ceiling_height)
    ramps, cores = _integer(rng, gen.ramps), _integer(rng, gen.cores)
    walls = {side: bool(rng.random() < gen.wall_bays) for side in "NSWE"}
    if not any(walls.values()):
        walls["N"] = True  # the ramps need a perimeter bay facing a lane
    lane_draw = float(rng.uniform(0.0, 1.0))  # drawn now, scaled once the bay width is known

    # Bands: rows north to south, columns west to east.
    rows = (["wall"] if walls["N"] else []) + ["aisle"]
    for _ in range(aisles - 1):
        rows += ["island", "island", "aisle"]
    rows += ["wall"] if walls["S"] else []
    # A blind aisle's last cell is its end, not part of a straight run: a blind block has one cell more.
    parts = {"|": ["cross"], "B": ["span"] * spans, "b": ["span"] * (spans + 1)}
    cols = (["wall"] if walls["W"] else []) + [c for part in template for c in parts[part]]
    cols += ["wall"] if walls["E"] else []
    m, n = len(rows), len(cols)
    aisle_rows = [i for i, r in enumerate(rows) if r == "aisle"]
    first, last = aisle_rows[0], aisle_rows[-1]

    S = np.full((m, n), PARKING, dtype=np.int8)
    for i in aisle_rows:
        S[i, [j for j, c in enumerate(cols) if c != "wall"]] = LANE
    for j, c in enumerate(cols):
        if c == "cross":
            S[first:last + 1, j] = LANE
    for i in (0, m - 1):
        for j in (0, n - 1):
            if rows[i] == "wall" and cols[j] == "wall":
                S[i, j] = OBSTACLE

    # Cores: an island's two rows at one span column between two spans (the spans beside a cross lane keep the
    # pillars at the corners' inner sides), never two side by side.
    islands = [(i, j) for i in range(m - 1) if rows[i] == "island" and rows[i + 1] == "island"
               for j, c in enumerate(cols) if 0 < j < n - 1 and c == cols[j - 1] == cols[j + 1] == "span"]
    taken: set[tuple[int, int]] = set()
    for k in rng.permutation(len(islands)) if islands else ():
        if len(taken) >= cores:
            break
        i, j = islands[int(k)]
        if (i, j - 1) in taken or (i, j + 1) in taken:
            continue
        taken.add((i, j))
        S[i:i + 2, j] = OBSTACLE

    # Ramps: perimeter bays facing a lane, where a ramp costs the plan least: a blind aisle's end first (the
    # aisle runs on out through the wall, or turns into the ramp), then the shortest straight stretch (a cross
    # lane between two aisles), a long aisle's cell, and last a junction or a corner (it would lose its kind);
    # the exit not beside the entrance.
    def lane_at(a: int, b: int) -> bool:
        return 0 <= a < m and 0 <= b < n and S[a, b] == LANE

    def stretch(a: int, b: int, da: int, db: int) -> int:
        """Straight lane cells from (a, b) on along (da, db), (a, b) not counted."""
        count = 0
        a, b = a + da, b + db
        while lane_at(a, b) and lane_at(a + da, b + db) and lane_at(a - da, b - db) \
                and not lane_at(a + db, b + da) and not lane_at(a - db, b - da):
            count += 1
            a, b = a + da, b + db
        return count

    def cost(i: int, j: int) -> float | None:
        if S[i, j] != PARKING:
            return None
        # the ramp runs straight out: a lane on one side, the outside on the other
        for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            a, b = i + di, j + dj
            if lane_at(a, b) and not (0 <= i - di < m and 0 <= j - dj < n):
                across = [lane_at(a + dj, b + di), lane_at(a - dj, b - di)]  # the lane's neighbours across the ramp
                ahead = lane_at(a + di, b + dj)
                if ahead and not any(across):  # a blind end the ramp runs on from
                    return 0.0
                if ahead:  # a junction or a corner: it would lose its kind
                    return 1000.0
                if all(across):  # a straight lane: the ramp splits its run
                    return 1.0 + stretch(a, b, dj, di) + stretch(a, b, -dj, -di)
                return 0.5 if any(across) else 500.0  # a blind end: the ramp turns it into a corner
        return None

    perimeter = sorted({(i, j) for i in range(m) for j in (0, n - 1)} | {(i, j) for i in (0, m - 1) for j in range(n)})
    placed: list[tuple[int, int]] = []
    for value in (ENTRANCE, EXIT)[:ramps]:
        found = [(c, i, j) for i, j in perimeter if all(abs(i - a) + abs(j - b) > 2 for a, b in placed)
                 and (c := cost(i, j)) is not None]
        if not found:
            continue  # a one-ramp garage: the entrance is two-way
        best = min(c for c, _, _ in found)
        pool = [(i, j) for c, i, j in found if c == best]
        i, j = pool[int(rng.integers(len(pool)))]
        S[i, j] = value
        placed.append((i, j))

    # A bay with no lane beside it (beside a ramp only, or at a blind aisle's island end) is a wall.
    lane = S == LANE
    near = np.zeros_like(lane)
    near[1:] |= lane[:-1]
    near[:-1] |= lane[1:]
    near[:, 1:] |= lane[:, :-1]
    near[:, :-1] |= lane[:, 1:]
    S[(S == PARKING) & ~near] = OBSTACLE

    # Dimensions. A span cell's end bays keep 2.40 m clear of the pillar at their corner (half a pillar between
    # two spans, a whole one where the pillar is pushed off a cross lane into the span); one bay a span keeps
    # 2.50 m between its two pillars.
    widths = []
    for j, c in enumerate(cols):
        if c != "span":
            continue
        shares = [pillar if k < 0 or k >= n or cols[k] != "span" else pillar / 2 for k in (j - 1, j + 1)]
        if per_span == 1:
            width = max(bay, BAY_BOTH_SIDES + sum(shares))
        else:
            width = per_span * max(bay, BAY_ONE_SIDE + max(shares))
        widths.append(_ceil_cm(width))
    # garage.bay_width: divides every span cell into per_span bays (scene/bays.py bay_count); floored to 0.1 mm.
    bay_width = math.floor(min(widths) / per_span * 1e4) / 1e4
    lane_lo = max(gen.lane_width[0], lane_minimum(bay_width))
    lane_width = _ceil_cm(lane_lo + lane_draw * max(0.0, gen.lane_width[1] - lane_lo))
    lane_width = min(max(lane_width, lane_lo), max(gen.lane_width[1], lane_lo))
    R = [lane_width if r == "aisle" else depth for r in rows]
    spans_iter = iter(widths)
    C = [lane_width if c == "cross" else next(spans_iter) if c == "span" else depth for c in cols]

    garage = [("bay_width", bay_width), ("pillar_size", pillar)]
    if ceiling is not None:
        garage.append(("ceiling_height", ceiling))
    name = f"generated_{family}_{seed}"
    plan = plan_from_lists(S, R, C, name, f"{WHERE} (plan.seed={seed})", garage=dict(garage))
    params = (("family", family), ("aisles", aisles), ("spans", spans), ("bays_per_span", per_span),
              ("bay_width", bay), ("bay_depth", depth), ("lane_width", lane_width), ("pillar_size", pillar),
              ("ceiling_height", ceiling), ("ramps", len(placed)), ("cores", len(taken)),
              ("wall_bays", "".join(s for s in "NSWE" if walls[s]) or "none"))
    return Draw(plan, seed, family, params)


def draw_yaml(d: Draw) -> str:
    """The draw as a plan file (`plan.file=` loads it back to the same plan, garage values included)."""
    plan = d.plan
    m, n = plan.shape
    width, depth = plan.size
    said = ", ".join(f"{k} {v}" for k, v in d.params)
    lines = [f"# Drawn by garage_exp/plan/generator.py, plan.seed={d.seed} ({m} x {n} cells, {width:.1f} x {depth:.1f} m).",
             f"# Drawn: {said}.",
             "# Reuse with plan.file=THIS_FILE; the garage values below set garage.* as the draw did.",
             f"name: {plan.name}", "S:"]
    lines += ["  - [" + ", ".join(f"{int(v):2d}" for v in row) + "]" for row in plan.S]
    lines.append("R: [" + ", ".join(repr(float(v)) for v in plan.R) + "]")
    lines.append("C: [" + ", ".join(repr(float(v)) for v in plan.C) + "]")
    lines.append("garage: {" + ", ".join(f"{k}: {float(v)!r}" for k, v in plan.garage) + "}")
    return "\n".join(lines) + "\n"


def draw_file(node: Any, seed: Any, folder: Path | None = None) -> Path:
    """The draw of `plan.generator` = node and `plan.seed` = seed as a plan file in the cache (named by its
    content, written once, atomically: every job of a sweep on one draw reads one file)."""
    from garage_exp.core.paths import cache_dir

    d = draw(generator_settings(node), check_seed(seed))
    text = draw_yaml(d)
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    folder = Path(folder) if folder is not None else cache_dir() / "plans"
    path = folder / f"{d.plan.name}-{digest}.yaml"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")  # jobs may run in threads side by side
        tmp.write_text(text)
        os.replace(tmp, path)
    return path
