"""Cell classification, rotations and the pillar grid on hand-made plans, and the features every shipped plan
must offer the experiments (cases 1-3)."""

from __future__ import annotations

import math
from itertools import combinations
from pathlib import Path

import pytest

from garage_exp.plan import classify, features, load_plan, plan_from_lists
from garage_exp.plan.model import STEPS
from garage_exp.core.paths import PLANS_DIR

SHIPPED = sorted(p for p in PLANS_DIR.iterdir() if p.suffix in (".yaml", ".yml", ".csv"))
# Plans written for the experiments; tiny.yaml is a smallest-useful example without a 4-cell straight.
EXPERIMENT_PLANS = [p for p in SHIPPED if p.stem != "tiny"]
PILLAR = 0.6


def centre_plan(centre: int, lane_sides: str):
    """5 x 5 plan: a lane ring (entrance at the top-left) around a 3 x 3 block whose centre cell (2, 2) has
    the value `centre` and lanes exactly on `lane_sides` (each connects straight out to the ring).
    The block's corner cells are bays, so the centre sees nothing but the chosen sides.

        2 1 1 1 1
        1 0 ? 0 1
        1 ? C ? 1
        1 0 ? 0 1
        1 1 1 1 1
    """
    S = [[1] * 5 for _ in range(5)]
    S[0][0] = 2
    for i in (1, 2, 3):
        for j in (1, 2, 3):
            S[i][j] = 0
    for side in lane_sides:
        di, dj = STEPS[side]
        S[2 + di][2 + dj] = 1
    S[2][2] = centre
    return plan_from_lists(S, [6.0] * 5, [6.0] * 5, f"centre_{centre}_{lane_sides or 'none'}")


ALL_SIDES = ["".join(c) for k in range(5) for c in combinations("NESW", k)]

# Expected by the method: lanes by count (2 adjacent = corner), rotation per the documented rule.
LANE_EXPECTED = {
    "N": ("straight", 90.0), "E": ("straight", 0.0), "S": ("straight", 90.0), "W": ("straight", 0.0),
    "NS": ("straight", 90.0), "EW": ("straight", 0.0),
    "NE": ("corner", 45.0), "ES": ("corner", 315.0), "SW": ("corner", 225.0), "NW": ("corner", 135.0),
    "NES": ("t_junction", 0.0), "ESW": ("t_junction", 270.0), "NSW": ("t_junction", 180.0),
    "NEW": ("t_junction", 90.0), "NESW": ("crossroads", 0.0),
}
PARKING_EXPECTED = {
    "": "type4", "N": "type3", "E": "type3", "S": "type3", "W": "type3",
    "NS": "type1", "EW": "type1", "NE": "type2", "ES": "type2", "SW": "type2", "NW": "type2",
    "NES": "type1", "ESW": "type1", "NSW": "type1", "NEW": "type1", "NESW": "type1",
}
YAWS = {"E": 0.0, "N": 90.0, "W": 180.0, "S": 270.0}


@pytest.mark.parametrize("sides", [s for s in ALL_SIDES if s])
def test_lane_type_and_rotation(sides):
    cell = classify(centre_plan(1, sides)).cell(2, 2)
    assert (cell.kind, cell.type, cell.rotation) == ("lane", *LANE_EXPECTED[sides])
    assert cell.lanes == tuple(sides)


@pytest.mark.parametrize("sides", ALL_SIDES)
def test_parking_type_and_rotation(sides):
    cell = classify(centre_plan(0, sides)).cell(2, 2)
    assert (cell.kind, cell.type) == ("parking", PARKING_EXPECTED[sides])
    if len(sides) == 1:
        assert cell.rotation == YAWS[sides]  # a bay faces its only lane
    elif sides:
        assert cell.rotation in [YAWS[d] for d in sides]  # faces one of its lanes
    else:
        assert cell.rotation == 0.0


def test_obstacle_has_no_type_whatever_its_neighbours():
    cell = classify(centre_plan(-1, "NESW")).cell(2, 2)
    assert (cell.kind, cell.type, cell.rotation, cell.driveable) == ("obstacle", "", 0.0, False)


def test_entrance_and_exit_face_their_lane_and_count_as_driveable():
    # 2 1 3 on one row, a bay under each.
    c = classify(plan_from_lists([[2, 1, 3], [0, 0, 0]], [6.0, 5.0], [6.0, 6.0, 6.0], "ramps"))
    entrance, lane, exit_ = c.cell(0, 0), c.cell(0, 1), c.cell(0, 2)
    assert (entrance.kind, entrance.type, entrance.lanes, entrance.rotation) == ("entrance", "straight", ("E",), 0.0)
    assert (exit_.kind, exit_.type, exit_.lanes, exit_.rotation) == ("exit", "straight", ("W",), 180.0)
    assert (lane.type, lane.lanes, lane.rotation) == ("straight", ("E", "W"), 0.0)
    assert entrance.driveable and exit_.driveable
    # A bay beside a ramp sees the ramp as a lane.
    assert (c.cell(1, 0).type, c.cell(1, 0).rotation) == ("type3", 90.0)


def test_tiny_plan_cell_by_cell():
    c = classify(load_plan(PLANS_DIR / "tiny.yaml"))
    expected = {  # (i, j): (kind, type, rotation), worked out by hand from the matrix in plans/tiny.yaml
        (0, 0): ("parking", "type3", 270.0), (0, 1): ("parking", "type3", 270.0),
        (0, 2): ("parking", "type3", 270.0), (0, 3): ("obstacle", "", 0.0),
        (1, 0): ("entrance", "straight", 0.0), (1, 1): ("lane", "straight", 0.0),
        (1, 2): ("lane", "corner", 225.0), (1, 3): ("parking", "type3", 180.0),
        (2, 0): ("parking", "type3", 90.0), (2, 1): ("parking", "type2", 90.0),
        (2, 2): ("lane", "straight", 90.0), (2, 3): ("parking", "type3", 180.0),
        (3, 0): ("obstacle", "", 0.0), (3, 1): ("parking", "type3", 0.0),
        (3, 2): ("exit", "straight", 90.0), (3, 3): ("obstacle", "", 0.0),
    }
    got = {(x.i, x.j): (x.kind, x.type, x.rotation) for x in c.all_cells()}
    assert got == expected


def test_pillars_of_a_two_by_two_plan():
    # 0 0      one interior vertex (1, 1), touching two bays; the lane row below pushes the pillar up
    # 2 1      into the bays by half its size.
    c = classify(plan_from_lists([[0, 0], [2, 1]], [5.0, 6.0], [2.5, 2.5], "p"))
    assert [(p.a, p.b, p.sx, p.sy) for p in c.pillars] == [(1, 1, 0, 1)]


def test_no_pillar_where_no_bay_touches():
    c = classify(plan_from_lists([[-1, -1], [2, 1]], [5.0, 6.0], [6.0, 6.0], "p"))
    assert c.pillars == ()


def _square(plan, p):
    x, y = plan.vertex(p.a, p.b)
    x, y = x + p.sx * PILLAR / 2, y + p.sy * PILLAR / 2
    return x - PILLAR / 2, y - PILLAR / 2, x + PILLAR / 2, y + PILLAR / 2


def pillar_problems(classified) -> list[str]:
    """Pillars in a driveable cell, and interior vertices next to a bay without a pillar."""
    plan = classified.plan
    problems = []
    for p in classified.pillars:
        x0, y0, x1, y1 = _square(plan, p)
        for cell in classified.all_cells():
            if not cell.driveable:
                continue
            cx0, cy0, cx1, cy1 = plan.cell_rect(cell.i, cell.j)
            overlap = min(x1, cx1) - max(x0, cx0), min(y1, cy1) - max(y0, cy0)
            if overlap[0] > 1e-9 and overlap[1] > 1e-9:
                problems.append(f"pillar at vertex ({p.a},{p.b}) stands in lane cell ({cell.i},{cell.j})")
    m, n = plan.shape
    have = {(p.a, p.b) for p in classified.pillars}
    for a in range(1, m):
        for b in range(1, n):
            touches_bay = any(plan.S[i, j] == 0 for i in (a - 1, a) for j in (b - 1, b))
            if touches_bay != ((a, b) in have):
                problems.append(f"vertex ({a},{b}): touches a bay {touches_bay}, pillar {(a, b) in have}")
    return problems


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_shipped_plan_pillars_stay_out_of_lanes(path):
    assert pillar_problems(classify(load_plan(path))) == []


# --- what the experiments need from every plan --------------------------------------------------------

def inner_vertex(cell) -> tuple[int, int]:
    """The grid vertex between a corner cell's two lane sides."""
    return (cell.i if "N" in cell.lanes else cell.i + 1, cell.j if "W" in cell.lanes else cell.j + 1)


def case1_corners(c) -> list:
    """Corner lane cells with a pillar at their inner corner."""
    pillars = {(p.a, p.b) for p in c.pillars}
    return [x for x in c.of_type("corner") if x.kind == "lane" and inner_vertex(x) in pillars]


def case2_bays(c) -> list:
    """Type3 bays facing a straight lane cell with a pillar at one of the two corners of their lane side."""
    plan = c.plan
    pillars = {(p.a, p.b) for p in c.pillars}
    found = []
    for bay in c.of_type("type3"):
        (side,) = bay.lanes
        di, dj = STEPS[side]
        lane = c.cell(bay.i + di, bay.j + dj)
        if lane.kind != "lane" or lane.type != "straight":
            continue
        if side in "NS":
            a = bay.i if side == "N" else bay.i + 1
            ends = [(a, bay.j), (a, bay.j + 1)]
        else:
            b = bay.j if side == "W" else bay.j + 1
            ends = [(bay.i, b), (bay.i + 1, b)]
        if pillars & set(ends):
            found.append(bay)
    assert all(plan.S[b.i, b.j] == 0 for b in found)
    return found


def case3_runs(c, min_cells: int = 4) -> list[list]:
    """Runs of >= min_cells straight lane cells along one axis with bays facing the run from one side
    beside at least half of its cells."""
    plan = c.plan
    runs = []
    for axis, step, sides in (("EW", (0, 1), "NS"), ("NS", (1, 0), "EW")):
        along = lambda x: x.kind == "lane" and x.type == "straight" and set(x.lanes) == set(axis)  # noqa: E731
        for start in c.all_cells():
            prev = (start.i - step[0], start.j - step[1])
            if not along(start) or (plan.inside(*prev) and along(c.cell(*prev))):
                continue
            run, (i, j) = [start], (start.i + step[0], start.j + step[1])
            while plan.inside(i, j) and along(c.cell(i, j)):
                run.append(c.cell(i, j))
                i, j = i + step[0], j + step[1]
            if len(run) < min_cells:
                continue
            for side in sides:
                di, dj = STEPS[side]
                facing = [x for x in run if plan.inside(x.i + di, x.j + dj)
                          and c.cell(x.i + di, x.j + dj).kind == "parking"
                          and c.cell(x.i + di, x.j + dj).type in ("type1", "type2", "type3")]
                if 2 * len(facing) >= len(run):
                    runs.append(run)
                    break
    return runs


@pytest.mark.parametrize("path", EXPERIMENT_PLANS, ids=lambda p: p.name)
def test_shipped_plan_has_what_the_cases_need(path):
    """The product's feature finders (garage_exp.plan.features) find each case's feature on the shipped plan,
    and what they find is what this file's independent helpers say the feature is. (Case 2's bay finder is
    exercised through build_scene in tests/test_cases.py.)"""
    c = classify(load_plan(path))
    corner = features.corner_nearest_entrance(c)
    assert corner.cell in case1_corners(c), "case 1: the product's corner has no pillar at its inner corner"
    assert (corner.pillar.a, corner.pillar.b) == inner_vertex(corner.cell)
    assert corner.approach_length > 10 and corner.exit_length > 5  # room for the approach and the target
    assert case2_bays(c), "case 2: no Type3 bay beside a pillar facing a straight lane"
    run = features.longest_straight_run(c, 4)
    assert any(run.cells == tuple(r) for r in case3_runs(c)), "case 3: the product's run is not a bay-lined run"
    assert len(run.cells) == max(len(r) for r in case3_runs(c))


@pytest.mark.parametrize("path", EXPERIMENT_PLANS, ids=lambda p: p.name)
def test_shipped_plan_dimensions_are_realistic(path):
    """Bays 5.0-5.3 m deep, lanes 6.0-6.5 m wide: every row or column holding a lane cell across its
    width is a lane width, and a bay's depth (across its lane side) is a bay depth."""
    c = classify(load_plan(path))
    plan = c.plan
    for x in c.all_cells():
        if x.kind == "lane" and x.type == "straight":
            width = plan.R[x.i] if x.rotation == 0.0 else plan.C[x.j]  # rotation 0: the lane runs E-W
            assert 6.0 <= width <= 6.5, f"lane ({x.i},{x.j}) is {width} m wide"
        if x.kind == "parking" and x.type == "type3":
            depth = plan.R[x.i] if x.lanes[0] in "NS" else plan.C[x.j]
            along = plan.C[x.j] if x.lanes[0] in "NS" else plan.R[x.i]
            assert 5.0 <= depth <= 5.3, f"bay ({x.i},{x.j}) is {depth} m deep"
            assert along >= 5.0 and math.floor(along / 2.5) >= 2, f"bay cell ({x.i},{x.j}) holds < 2 bays"


def test_research_csv_is_the_research_plan():
    yaml_plan, csv_plan = load_plan(PLANS_DIR / "research.yaml"), load_plan(PLANS_DIR / "research_csv.csv")
    assert csv_plan.S.tolist() == yaml_plan.S.tolist()
    assert csv_plan.R.tolist() == yaml_plan.R.tolist() and csv_plan.C.tolist() == yaml_plan.C.tolist()


@pytest.mark.parametrize("name, junctions", [
    ("research", {"corner": 2, "t_junction": 2}),
    ("realistic", {"corner": 3, "t_junction": 2, "crossroads": 1}),
    ("obstacles", {"corner": 2, "t_junction": 2}),
])
def test_shipped_plan_layouts(name, junctions):
    c = classify(load_plan(PLANS_DIR / f"{name}.yaml"))
    lanes = [x for x in c.all_cells() if x.kind == "lane"]
    for kind in ("corner", "t_junction", "crossroads"):
        assert sum(x.type == kind for x in lanes) == junctions.get(kind, 0), kind
    assert len(c.of_type("entrance")) == 1 and len(c.of_type("exit")) == 1
    # Ramps go through the outer wall.
    m, n = c.plan.shape
    for ramp in c.of_type("entrance") + c.of_type("exit"):
        assert ramp.i in (0, m - 1) or ramp.j in (0, n - 1)
    if name == "obstacles":
        assert len(c.of_type("obstacle")) >= 8  # cores, plant room, ramp block besides the outer corners
    if name == "realistic":
        width, depth = c.plan.size
        assert 55 <= width <= 65 and 38 <= depth <= 46


def test_no_shipped_bay_faces_a_ramp():
    """A bay whose rotation points at an entrance or exit cell would park cars nose-first into the ramp."""
    for path in EXPERIMENT_PLANS:
        c = classify(load_plan(path))
        for x in c.of_type("parking"):
            side = next((d for d, yaw in YAWS.items() if yaw == x.rotation), None)
            if side and side in x.lanes:
                di, dj = STEPS[side]
                assert c.cell(x.i + di, x.j + dj).kind == "lane", f"{path.name}: bay ({x.i},{x.j}) faces a ramp"


def test_shipped_plan_list_is_complete():
    names = {p.name for p in SHIPPED}
    assert {"research.yaml", "realistic.yaml", "obstacles.yaml", "research_csv.csv", "tiny.yaml"} <= names
    assert all(isinstance(p, Path) for p in SHIPPED)


@pytest.mark.parametrize("path", EXPERIMENT_PLANS, ids=lambda p: p.name)
def test_case1_corner_has_room_for_the_default_run(path):
    """The corner the experiments pick (features.corner_nearest_entrance) leaves room for case 1's default
    start and target distances (conf/case/1.yaml) plus half a long car, so the run is not cut short."""
    import yaml

    from garage_exp.core.paths import PROJECT_ROOT
    from garage_exp.plan.features import corner_nearest_entrance

    case = yaml.safe_load((PROJECT_ROOT / "conf" / "case" / "1.yaml").read_text())
    corner = corner_nearest_entrance(classify(load_plan(path)))
    half_car = 2.5
    assert corner.approach_length >= case["motion"]["start"] + half_car + 0.2
    assert corner.exit_length >= case["actors"]["target"]["distance"] + half_car + 0.2
