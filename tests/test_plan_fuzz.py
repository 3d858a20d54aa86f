"""Fuzzing the plan loader: whatever S, R, C or file text a user writes, loading either gives a Plan or raises
GarageError (one line naming the place), never another exception; plans that load classify consistently."""

from __future__ import annotations

import math
from collections import deque

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from garage_exp.core.errors import GarageError
from garage_exp.plan import classify, load_plan, plan_from_lists
from garage_exp.plan.classify import LANE_TYPES, PARKING_TYPES

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

# Mostly plausible values, with every kind of wrong one mixed in.
s_value = st.one_of(
    st.integers(-1, 3), st.integers(-1, 3), st.integers(-1, 3),
    st.integers(), st.booleans(), st.none(), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=3), st.lists(st.integers(-1, 3), max_size=2),
)
metres = st.one_of(
    st.floats(0.5, 100.0), st.integers(1, 100), st.floats(allow_nan=True, allow_infinity=True),
    st.integers(), st.booleans(), st.none(), st.text(max_size=3), st.lists(st.floats(1, 10), max_size=2),
    st.integers(10**309, 10**310),  # beyond float range: float() overflows
)


@st.composite
def raw_plans(draw):
    """S, R, C that are often well formed (so the later checks, down to connectivity, get exercised) and
    often not, in every way at once. Branches are picked explicitly: st.one_of would flatten the nested
    one_of of scalars and draw a scalar S most of the time."""
    m, n = draw(st.integers(1, 6)), draw(st.integers(1, 6))
    S = {
        "clean": lambda: draw(st.lists(st.lists(st.integers(-1, 3), min_size=n, max_size=n), min_size=m,
                                       max_size=m)),
        "messy": lambda: draw(st.lists(st.lists(s_value, min_size=max(n - 1, 0), max_size=n + 1), min_size=1,
                                       max_size=m + 1)),
        "scalar": lambda: draw(s_value),
    }[draw(st.sampled_from(["clean", "clean", "clean", "messy", "scalar"]))]()

    def vector(length: int):
        good = st.one_of(st.floats(0.5, 100.0), st.integers(1, 100))
        return {
            "good": lambda: draw(st.lists(good, min_size=length, max_size=length)),
            "values": lambda: draw(st.lists(metres, min_size=length, max_size=length)),
            "length": lambda: draw(st.lists(good, max_size=7)),
            "nested": lambda: draw(st.lists(st.lists(metres, min_size=1, max_size=length + 1), max_size=length + 1)),
            "scalar": lambda: draw(metres),
        }[draw(st.sampled_from(["good", "good", "values", "values", "length", "nested", "scalar"]))]()

    return S, vector(m), vector(n)


def check_loaded_or_garage_error(load) -> None:
    try:
        plan = load()
    except GarageError as exc:
        assert "\n" not in str(exc)
        return
    classified = classify(plan)
    assert len(list(classified.all_cells())) == plan.S.size


@FUZZ
@given(raw_plans())
def test_plan_from_lists_loads_or_raises_garage_error(raw):
    check_loaded_or_garage_error(lambda: plan_from_lists(*raw, name="fuzz"))


@FUZZ
@given(raw_plans(), st.one_of(st.none(), st.text(max_size=5), st.integers(), st.lists(st.integers(), max_size=2)))
def test_yaml_file_loads_or_raises_garage_error(tmp_path, raw, name):
    S, R, C = raw
    data = {"S": S, "R": R, "C": C} if name is None else {"S": S, "R": R, "C": C, "name": name}
    path = tmp_path / "fuzz.yaml"
    path.write_text(yaml.safe_dump(data))
    check_loaded_or_garage_error(lambda: load_plan(path))


@FUZZ
@given(st.text(max_size=300), st.sampled_from(["fuzz.yaml", "fuzz.csv"]))
def test_any_text_loads_or_raises_garage_error(tmp_path, text, name):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    check_loaded_or_garage_error(lambda: load_plan(path))


@FUZZ
@given(st.binary(max_size=300), st.sampled_from(["fuzz.yaml", "fuzz.csv"]))
def test_any_bytes_load_or_raise_garage_error(tmp_path, data, name):
    path = tmp_path / name
    path.write_bytes(data)
    check_loaded_or_garage_error(lambda: load_plan(path))


csv_field = st.one_of(st.integers(-2, 4).map(str), st.floats(0.1, 120).map(lambda v: f"{v:.2f}"),
                      st.sampled_from(["", " 1 ", "nan", "inf", "-inf", "1e3", "x", '"1"', "#", "2.0"]))


@FUZZ
@given(st.lists(st.lists(csv_field, min_size=1, max_size=5), min_size=1, max_size=6))
def test_csv_grid_loads_or_raises_garage_error(tmp_path, grid):
    path = tmp_path / "fuzz.csv"
    path.write_text("\n".join(",".join(row) for row in grid) + "\n", encoding="utf-8")
    check_loaded_or_garage_error(lambda: load_plan(path))


# --- valid plans: they must load, and classification must agree with the method ---------------------

def _reachable(S: list[list[int]], m: int, n: int) -> set[tuple[int, int]]:
    seen = {(i, j) for i in range(m) for j in range(n) if S[i][j] == 2}
    queue = deque(seen)
    while queue:
        i, j = queue.popleft()
        for a, b in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)):
            if 0 <= a < m and 0 <= b < n and (a, b) not in seen and S[a][b] in (1, 2, 3):
                seen.add((a, b))
                queue.append((a, b))
    return seen


@st.composite
def valid_plans(draw):
    m, n = draw(st.integers(1, 8)), draw(st.integers(1, 8))
    S = [[draw(st.sampled_from([-1, 0, 0, 1, 1, 1, 3])) for _ in range(n)] for _ in range(m)]
    S[draw(st.integers(0, m - 1))][draw(st.integers(0, n - 1))] = 2
    reach = _reachable(S, m, n)
    S = [[v if v not in (1, 3) or (i, j) in reach else 0 for j, v in enumerate(row)] for i, row in enumerate(S)]
    R = draw(st.lists(st.floats(0.5, 100.0), min_size=m, max_size=m))
    C = draw(st.lists(st.floats(0.5, 100.0), min_size=n, max_size=n))
    return S, R, C


@FUZZ
@given(valid_plans())
def test_valid_plans_load_and_classify_by_the_method(raw):
    S, R, C = raw
    plan = plan_from_lists(S, R, C, "valid")
    classified = classify(plan)
    m, n = plan.shape
    assert math.isclose(plan.size[0], sum(C)) and math.isclose(plan.size[1], sum(R))
    for cell in classified.all_cells():
        drive = [d for d, a, b in plan.neighbours(cell.i, cell.j) if S[a][b] in (1, 2, 3)]
        assert list(cell.lanes) == drive
        k = len(drive)
        opposite = k == 2 and set(drive) in ({"N", "S"}, {"E", "W"})
        if cell.kind == "parking":
            expected = "type1" if k >= 3 or opposite else {2: "type2", 1: "type3", 0: "type4"}[k]
            assert cell.type == expected and cell.type in PARKING_TYPES
        elif cell.kind in ("lane", "entrance", "exit"):
            expected = {4: "crossroads", 3: "t_junction"}.get(k, "corner" if k == 2 and not opposite else "straight")
            assert cell.type == expected and cell.type in LANE_TYPES
        else:
            assert cell.type == ""
        assert 0.0 <= cell.rotation < 360.0
    for p in classified.pillars:
        assert 1 <= p.a < m and 1 <= p.b < n and p.sx in (-1, 0, 1) and p.sy in (-1, 0, 1)
