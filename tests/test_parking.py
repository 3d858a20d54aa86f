"""Parked cars (the occupancy factor) and the cases' vehicles, as geometry: no SAPIEN needed."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require

from garage_exp.scene.schema import GarageConf, LightConf, PaletteConf
from garage_exp.core.paths import PLANS_DIR
from garage_exp.plan import classify, load_plan
from garage_exp.scene.bays import bays, overlap
from garage_exp.scene.parking import car_footprint, park_vehicles, pillar_footprints
from garage_exp.scene.structure import build_garage
from garage_exp.run.spec import scene_spec


@pytest.fixture(scope="module")
def library():
    from garage_exp.assets.vehicles import VehicleLibrary

    require("vehicles")
    return VehicleLibrary()


def park(plan: str, occupancy: float, seed: int, library, classes=("small", "medium", "large")):
    classified = classify(load_plan(PLANS_DIR / f"{plan}.yaml"))
    garage = GarageConf()
    scene = build_garage(classified, garage, LightConf())
    palette = PaletteConf(parked_occupancy=occupancy, parked_classes=list(classes))
    cars = park_vehicles(classified, garage, palette, library, np.random.default_rng(seed), scene)
    return classified, garage, scene, cars


def inside(inner, outer, tol=1e-6):
    return (inner[0] >= outer[0] - tol and inner[1] >= outer[1] - tol and inner[2] <= outer[2] + tol
            and inner[3] <= outer[3] + tol)


@pytest.mark.parametrize("plan", ["research", "realistic"])
def test_parked_cars_stand_in_their_bays_clear_of_pillars_and_each_other(plan, library):
    classified, garage, scene, cars = park(plan, 0.7, 0, library)
    all_bays = bays(classified, garage)
    assert len(cars) >= 0.6 * len(all_bays)  # a bay nothing fits in may stay empty, but few do
    pillars = pillar_footprints(scene)
    footprints = []
    for car in cars:
        bay = next(b for b in all_bays if abs(b.x - car.pose.x) < 1e-9 and abs(b.y - car.pose.y) < 1e-9)
        assert car.pose.yaw == bay.yaw  # aligned to its bay, nose to the lane
        length, width, height = car.extent
        foot = car_footprint(car.pose.x, car.pose.y, car.pose.yaw, length, width)
        # Lengthwise inside the bay; mirrors may reach 7.5 cm past a line sideways.
        bx0, by0, bx1, by1 = bay.rect
        assert inside(foot, (bx0 - 0.08, by0 - 0.08, bx1 + 0.08, by1 + 0.08))
        assert not any(overlap(foot, p) > 0 for p in pillars)
        assert height < garage.ceiling_height
        footprints.append(foot)
    for a in range(len(footprints)):
        for b in range(a + 1, len(footprints)):
            assert overlap(footprints[a], footprints[b]) <= 0.2  # neighbours' mirrors at most brush


def test_occupancy_is_a_seeded_fraction(library):
    _, _, _, none = park("research", 0.0, 0, library)
    _, _, _, few = park("research", 0.2, 0, library)
    _, _, _, many = park("research", 0.8, 0, library)
    assert none == [] and 0 < len(few) < len(many)
    _, _, _, again = park("research", 0.8, 0, library)
    _, _, _, other = park("research", 0.8, 1, library)
    poses = lambda cars: [(c.pose, c.model) for c in cars]  # noqa: E731
    assert poses(again) == poses(many)
    assert poses(other) != poses(many)


def test_parked_classes_are_respected(library):
    _, _, _, cars = park("research", 0.5, 0, library, classes=("small",))
    assert cars and {c.size_class for c in cars} == {"small"}


def test_bad_occupancy_is_one_line():
    from garage_exp.core.errors import GarageError
    from garage_exp.scene.parking import check_palette

    with pytest.raises(GarageError, match="parked_occupancy") as info:
        check_palette(PaletteConf(parked_occupancy=1.5))
    assert "\n" not in str(info.value)


def test_case_3_cars_stand_in_the_bays_beside_the_lane(library):
    from garage_exp.scenario import make_case

    from conftest import compose_cfg

    classified = classify(load_plan(PLANS_DIR / "research.yaml"))
    cfg = compose_cfg("case=3", "case.variants=[{show: [far_small], target: far_small},"
                      "{show: [close_large, far_medium], target: far_medium}]")
    setup = make_case(scene_spec(cfg), classified, library, np.random.default_rng(0))
    parked = [v for v in setup.vehicles if v.role == "parked"]
    assert {v.name for v in parked} == {"far_small", "close_large", "far_medium"}
    all_bays = bays(classified, GarageConf())
    for v in parked:
        bay = next(b for b in all_bays if abs(b.x - v.pose.x) < 1e-9 and abs(b.y - v.pose.y) < 1e-9)
        assert v.pose.yaw == bay.yaw and v.extent[0] <= bay.depth + 0.3
    # Far is farther from the ego's path start than close, along the driving direction.
    ego0 = setup.shots[0].ego
    dist = {v.name: np.hypot(v.pose.x - ego0.x, v.pose.y - ego0.y) for v in parked}
    assert dist["close_large"] < dist["far_small"]
    assert [s.target for s in setup.shots] == ["far_small"] * 5 + ["far_medium"] * 5


def test_a_plans_bays_are_made_once_for_its_sizes_and_afresh_for_other_sizes(monkeypatch):
    """scene.bays.bays keeps each plan's bays by its sizes (a scene's build asks for them ~9 times): a second call
    makes none, a copy each time (a caller's list is its own), other sizes are made afresh."""
    from types import SimpleNamespace

    from garage_exp.plan import classify, load_plan
    from garage_exp.scene import bays as bays_mod

    from garage_exp.core.paths import PLANS_DIR

    classified = classify(load_plan(PLANS_DIR / "small.yaml"))
    made = []
    real = bays_mod._all_bays
    monkeypatch.setattr(bays_mod, "_all_bays", lambda *args: made.append(args[1:]) or real(*args))
    garage = SimpleNamespace(bay_width=2.5, pillar_size=0.6)
    first = bays_mod.bays(classified, garage)
    first.clear()
    again = bays_mod.bays(classified, garage)
    assert again and again == real(classified, 2.5, 0.6) and made == [(2.5, 0.6)]
    assert bays_mod.bays(classified, SimpleNamespace(bay_width=2.7, pillar_size=0.6)) != again
    assert made == [(2.5, 0.6), (2.7, 0.6)]
