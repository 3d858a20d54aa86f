"""The OpenSCENARIO importer on small files of its own (tests/xosc_files.py; issue 42's items 13-19): the standard's
expression grammar, controllers reported, vehicle categories and sizes as the vehicle library has them, a case
that would not run refused at import, timed and many-vertex polyline trajectories kept as motion. Bad files are
in the bad-input corpus (`xosc-*` entries of tests/bad_inputs/cases.yaml)."""

from __future__ import annotations

import math

import pytest
import yaml
from test_cases import library  # noqa: F401  (the module-scoped vehicle library)
from xosc_files import (CONTROLLER, EGO, PERSON, event, pedestrian, polyline, scenario, speed, teleport,
                        vehicle, write)


def imported(tmp_path, capsys, text: str, *args: str) -> tuple[dict, str]:
    from garage_exp.openscenario.xosc_import import main

    path = write(tmp_path, "s.xosc", text)
    out = tmp_path / "case" / "s.yaml"
    assert main([str(path), "-o", str(out), *args]) == 0, capsys.readouterr().err
    return yaml.safe_load(out.read_text()), capsys.readouterr().out


@pytest.mark.parametrize("text, value", [
    ("atan(1) * 4", math.pi), ("asin(1) + acos(1)", math.pi / 2), ("sign(-3) * abs(-2)", -2.0),
    ("pow(2, 10) + sqrt(16)", 1028.0), ("max(1, $a, 3) - min($a, 0.5)", 2.5), ("7 % -3", 1.0), ("-7 % 3", -1.0),
    ("-2 ** 2", -4.0), ("floor(-1.5) + ceil(1.2)", 0.0),
    ("round(2.5)", 3.0), ("round(-2.5)", -3.0),  # halves away from zero (half to even: 2, -2; half up: 3, -2)
    ("tan(0) + cos(0) + sin(0)", 1.0), ("($a + 1) * 2 / 4", 1.5),
    ("not ($a >= 2) or false", False), ("not ($a > 2)", True), ("$a >= 2 and $a != 3 and true", True), ("1 < $a < 3", True),
    ("$flag and 2 == 2", True)])
def test_the_standards_expressions_evaluate(text, value):
    from garage_exp.openscenario.xosc_params import _evaluate

    assert _evaluate(text, {"a": "2", "flag": "true"}) == pytest.approx(value)


@pytest.mark.parametrize("text, says", [
    ("10.0**400", "beyond a double's range"), ("10**10**10", "beyond a double's range"),
    ("1e308 * 10", "beyond a double's range"), ("1 / 0", "division by zero"), ("asin(2)", "outside its function"),
    ("log(2)", "no function log()"), ("max()", "one or more"), ("pow(2)", "takes 2"), ("$b + 1", "unknown name 'b'"),
    ("__import__('os')", "no function __import__()"), ("[1, 2]", "not an OpenSCENARIO expression"),
    ("1 +", "syntax error"), ("(" * 300 + "1" + ")" * 300, "syntax error|nested too deeply")])
def test_a_bad_expression_is_a_value_error(text, says):
    from garage_exp.openscenario.xosc_params import _evaluate

    with pytest.raises(ValueError, match=says.replace("(", r"\(").replace(")", r"\)")):
        _evaluate(text, {"a": "2"})


def test_a_parameter_using_atan_imports(tmp_path, capsys):
    """Euro NCAP CPTA's parameters use atan: the walker's offset is computed from one."""
    text = scenario(vehicle("Ego") + pedestrian("Walker"), {**EGO, "Walker": teleport(40, "$Side")},
                    params={"Side": "${-4 * atan(1) / pi}"})  # -1
    case, _ = imported(tmp_path, capsys, text)
    assert case["actors"]["walker"]["offset"] - case["actors"]["ego"]["offset"] == pytest.approx(-1.0)


def test_a_controller_is_a_left_out_line(tmp_path, capsys):
    text = scenario(vehicle("Ego", controller=CONTROLLER) + pedestrian("Walker"), {**EGO, **PERSON})
    case, printed = imported(tmp_path, capsys, text)
    line = next(ln for ln in printed.splitlines() if "ObjectController" in ln)
    assert line.startswith("left out") and "Ego's controller (DriverModel)" in line
    assert "ObjectController" in (tmp_path / "case" / "s.yaml").read_text()  # kept at the top of the YAML


@pytest.mark.parametrize("category, length, height, size, body, note", [
    ("car", 4.3, 1.45, "small", "car", False),     # the library's small (< 4.4 m); the old cut-off said medium
    ("car", 4.9, 1.5, "medium", "car", False),     # the library's medium (<= 5.0 m); the old cut-off said large
    ("car", 5.2, 1.5, "medium", "car", True),      # longer than any car of the library: its largest cars
    ("car", 4.6, 2.0, "medium", "car", True),      # taller than 1.9 m: large by size, and no car is large
    ("van", 4.3, 1.9, "large", "van", True),       # every van of the library is large
    ("bus", 10.0, 3.0, "large", "bus", False),
    ("semitrailer", 12.0, 3.8, "large", "truck", False)])
def test_vehicle_sizes_are_the_librarys(tmp_path, capsys, category, length, height, size, body, note):
    from garage_exp.assets.vehicles import SIZES_OF_KIND

    text = scenario(vehicle("Ego") + pedestrian("Walker") + vehicle("Other", category, length, height),
                    {**EGO, **PERSON, "Other": teleport(30, 3.5)})
    case, printed = imported(tmp_path, capsys, text)
    other = case["actors"]["other"]
    assert (other["size"], other["body"]) == (size, body)
    assert other["size"] in SIZES_OF_KIND[other["body"]]
    assert ("the vehicle library's" in printed) == note, printed


def test_the_size_table_is_the_vehicle_librarys():
    """SIZES_OF_KIND says which size classes the library holds of each kind: checked against its models."""
    from conftest import require

    require("vehicles")
    from garage_exp.assets.vehicles import SIZES_OF_KIND, VehicleLibrary

    held = {}
    for model in VehicleLibrary().models:
        held.setdefault(model.kind, set()).add(model.size_class)
    assert {k: set(v) for k, v in SIZES_OF_KIND.items()} == held


def test_no_target_is_refused_at_import_and_target_names_one(tmp_path, capsys):
    from garage_exp.openscenario.xosc_import import main

    text = scenario(vehicle("Ego") + vehicle("Parked", length=4.6), {**EGO, "Parked": teleport(40, 2.0)})
    path = write(tmp_path, "s.xosc", text)
    out = tmp_path / "case" / "s.yaml"
    assert main([str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no target" in err and "--target ENTITY" in err and not out.exists()
    assert main([str(path), "-o", str(out), "--target", "Nobody"]) == 2
    assert "--target Nobody: no entity of that name" in capsys.readouterr().err
    case, _ = imported(tmp_path, capsys, text, "--target", "Parked")
    assert case["target"] == "parked" and case["actors"]["parked"]["role"] == "target"


def test_a_timed_polyline_walks(tmp_path, capsys):
    """ALKS 4.2.3's crossing pedestrian: a FollowTrajectoryAction whose polyline's vertices have times, started by
    an event, and no SpeedAction: it walks its 6 m across in 4.8 s, from 2 s on (the ego then 5 m on)."""
    walk = polyline([(45, -3.0), (45, 3.0)], times=[0.0, 4.8])
    text = scenario(vehicle("Ego") + pedestrian("Walker"), {**EGO, "Walker": teleport(45, -3.0, math.pi / 2)},
                    story=event("Walker", walk, at_time=2.0))
    case, printed = imported(tmp_path, capsys, text)
    along = case["motion"]["along"]["walker"]
    assert along["key"] == "offset" and along["end"] - along["start"] == pytest.approx(6.0, abs=1e-3)
    assert along["speed"] == pytest.approx(1.25) and along["at"] == pytest.approx(case["motion"]["start"] - 5.0)
    assert "path" not in along and "left standing" not in printed


def test_a_timed_polyline_with_an_offset_and_uneven_legs(tmp_path, capsys):
    from garage_exp.openscenario.xosc_read import read

    walk = polyline([(45, -3.0), (45, 0.0), (45, 3.0)], times=[1.0, 2.0, 5.0]).replace('offset="0.0"/>',
                                                                                      'offset="0.5"/>')
    text = scenario(vehicle("Ego") + pedestrian("Walker"), {**EGO, "Walker": teleport(45, -3.0, math.pi / 2)},
                    story=event("Walker", walk, at_time=2.0))
    r = read(write(tmp_path, "s.xosc", text))
    move = next(m for m in r.moves["Walker"] if m.speed)
    assert move.speed == pytest.approx(1.5) and move.trigger == ("time", pytest.approx(3.5))  # 2 s + 1 s + 0.5 s
    assert any("walked at their mean" in line for line in r.left_out)


def test_every_vertex_of_a_polyline_is_kept(tmp_path, capsys, library):
    """esmini's alks_pedestrian: a trajectory of three vertices (9 m across the road, then 10 m along it) and a
    SpeedAction at 2 s. All three are kept as the co-motion's path, and the built frames walk it: across first,
    then along, turning as the path turns."""
    from test_cases import build

    walk = polyline([(30, -4.0), (30, 5.0), (40, 5.0)])
    text = scenario(vehicle("Ego") + pedestrian("Walker"), {"Ego": teleport(10) + speed(4.0), "Walker": walk},
                    story=event("Walker", speed(1.5), at_time=2.0))
    case, printed = imported(tmp_path, capsys, text)
    along = case["motion"]["along"]["walker"]
    walker = case["actors"]["walker"]
    assert len(along["path"]) == 3 and "kept as a path" in printed
    (d0, o0), (d1, o1), (d2, o2) = along["path"]
    assert (d0, o0) == (pytest.approx(walker["distance"]), pytest.approx(walker["offset"]))
    assert o1 - o0 == pytest.approx(9.0, abs=1e-3) and d1 == pytest.approx(d0, abs=1e-3)
    assert d2 - d1 == pytest.approx(-10.0, abs=1e-3) and o2 == pytest.approx(o1, abs=1e-3)
    assert along["speed"] == 1.5 and along["at"] == pytest.approx(case["motion"]["start"] - 8.0)

    # the frames: a shorter walk that fits the research plan's lane (1.5 m across, 3 m along)
    along["path"] = [[d0, 0.0], [d0, 1.5], [d0 - 3.0, 1.5]]
    walker["offset"], walker["distance"] = 0.0, d0
    del along["at"]  # from the first frame: 3.5 s of the ego's 14 m, 5.25 m at 1.5 m/s, past the path's 4.5 m
    case["motion"]["end"] = d0 + 6.0
    out = tmp_path / "conf" / "case" / "walk.yaml"
    out.parent.mkdir(parents=True)
    out.write_text(yaml.safe_dump(case))
    _, _, _, setup = build(library, "case=walk", "ego.speed=14.4", f"hydra.searchpath=[file://{tmp_path / 'conf'}]")
    poses = [s.poses["walker"] for s in setup.shots]
    first, last = poses[0], poses[-1]
    assert len({(round(p.x, 3), round(p.y, 3)) for p in poses}) > 3  # it moves, frame by frame
    walked = math.hypot(last.x - first.x, last.y - first.y)
    assert walked == pytest.approx(math.hypot(1.5, 3.0), abs=0.05)  # to the path's end, not its first leg's
    assert abs(((last.yaw - first.yaw) + 180) % 360 - 180) == pytest.approx(90.0, abs=0.5)  # turned with the path


def test_a_time_headway_trigger_starts_the_walk(tmp_path, capsys):
    """ALKS 4.2.3's CrossStartCondition: the walker sets off when the ego is 3.6 s from it (freespace), not at
    the first frame."""
    walk = polyline([(45, -3.0), (45, 3.0)], times=[0.0, 4.8])
    headway = ('<ByEntityCondition><TriggeringEntities triggeringEntitiesRule="any"><EntityRef entityRef="Ego"/>'
               '</TriggeringEntities><EntityCondition><TimeHeadwayCondition entityRef="Walker" value="3.6" '
               'freespace="true" rule="lessThan" coordinateSystem="road" relativeDistanceType="longitudinal"/>'
               '</EntityCondition></ByEntityCondition>')
    story = event("Walker", walk).replace(
        '<ByValueCondition><SimulationTimeCondition value="0.0" rule="greaterThan"/></ByValueCondition>', headway, 1)
    assert "TimeHeadwayCondition" in story
    text = scenario(vehicle("Ego") + pedestrian("Walker"), {**EGO, "Walker": teleport(45, -3.0, math.pi / 2)},
                    story=story)
    case, printed = imported(tmp_path, capsys, text)
    along, walker = case["motion"]["along"]["walker"], case["actors"]["walker"]
    # 3.6 s at 2.5 m/s = 9 m between the ego's front and the walker's back: their centres 9 + (4.4 + 0.4) / 2 apart
    assert along["at"] == pytest.approx(walker["distance"] + 9.0 + 2.4, abs=1e-3)
    assert "3.6 s from 'Walker'" in printed and "taken as the start" not in printed
