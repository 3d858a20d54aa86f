"""OpenSCENARIO 1.0, for CARLA's ScenarioRunner (its reader takes 1.0 only; `export.openscenario_version=1.0`):
the blueprints it spawns for our bodies and people, and what 1.0 cannot say, refused in one line. The writer
(xosc_write.py) leaves out of a 1.0 file what 1.0 lacks: expressions, synchronised arrivals, greaterOrEqual, a
Polyline without vertex times."""

from __future__ import annotations

from garage_exp.core.errors import GarageError
from garage_exp.openscenario.model import Track

# CARLA 0.9.x blueprints for our bodies and people (ScenarioRunner spawns a Vehicle's `name`, a Pedestrian's
# `model`)
CARLA_VEHICLES = {"car": "vehicle.tesla.model3", "suv": "vehicle.nissan.patrol", "pickup": "vehicle.ford.ranger",
                  "van": "vehicle.volkswagen.t2", "bus": "vehicle.mitsubishi.fusorosa",
                  "truck": "vehicle.carlamotors.carlacola"}
CARLA_WALKERS = {"adult": "walker.pedestrian.0001", "child": "walker.pedestrian.0009"}


def vehicle(body: str) -> str:
    """The blueprint ScenarioRunner spawns for one of our bodies (a car's for a body it has none for)."""
    return CARLA_VEHICLES.get(body, CARLA_VEHICLES["car"])


def walker(size_class: str | None) -> str:
    """The walker blueprint for a person of our size class (an adult's when it has none)."""
    return CARLA_WALKERS.get(size_class or "adult", CARLA_WALKERS["adult"])


def check_tracks(version: str, label: str, moving: list[Track]) -> None:
    """What OpenSCENARIO `version` cannot say, refused in one line: 1.0 for ScenarioRunner has no negative
    speed, so no reversing ego."""
    ego = next((t for t in moving if t.name == "ego"), None)
    if version == "1.0" and ego is not None and ego.velocity < 0:
        raise GarageError(f"CARLA's ScenarioRunner (OpenSCENARIO 1.0) refuses negative speeds: the ego reverses in "
                          f"variant {label!r}; export it as 1.2", "export.openscenario_version")
