"""A draw's first look from plain data (search/plain_draw.py): its settings equal the composed config's, and its
verdict the full check's, on drawn points of the wide space; what it cannot make exactly is left to the full check."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import optuna.distributions as od
import pytest
from conftest import hydra_loader, recording_launch
from omegaconf import OmegaConf

from garage_exp.core.errors import Infeasible, Screened
from garage_exp.core.plain import settings
from garage_exp.search.plain_draw import Base, first_look
from garage_exp.search.require import Require
from garage_exp.search.require import first_look as actors_look

RULE = Require(min_visible=0.3, min_box=25.0, max_distance=30.0, max_truncation=0.5)


@dataclass
class Occluder:  # a small typed config for the fallbacks' test
    length: float = 1.0
    width: float = "${.length}"  # type: ignore[assignment]  # an interpolation, typed by its field
    height: float = "${garage.ceiling}"  # type: ignore[assignment]


@dataclass
class Garage:
    ceiling: float = 2.5


@dataclass
class Config:
    occluder: Occluder = field(default_factory=Occluder)
    garage: Garage = field(default_factory=Garage)
    label: str = "car-${garage.ceiling}"
    seed: int = 1


def draw(space, rng, number: int) -> list[str]:
    """A random point of the space as the search's loop writes it, on one of four generated garages."""
    values = {}
    for name, dist in space.params.items():
        if isinstance(dist, od.CategoricalDistribution):
            values[name] = dist.choices[rng.integers(len(dist.choices))]
        elif isinstance(dist, od.IntDistribution):
            values[name] = int(rng.integers(dist.low, dist.high + 1))
        else:
            values[name] = float(rng.uniform(dist.low, dist.high))
    values["plan.seed"] = number % 4
    # a search's store, which a resolver reads (detector.registry: ${oc.select:tracking.uri,null})
    return [*space.overrides(values), "tracking.uri=sqlite:///nowhere.db", f"search.trial={number}"]


def same(a, b) -> bool:
    """Equal and of the same types all the way down (3 == 3.0, but a float key holds a float)."""
    if isinstance(a, dict) or isinstance(b, dict):
        return type(a) is type(b) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def full_check(cfg):
    """The search's check of one composed draw (search/loop.py `rejects`): Infeasible, the first look's
    rejection, or None when the placed actors pass it."""
    from garage_exp.run.preflight import preflight
    from garage_exp.scene.camera import scored_camera

    def screen(job, setup, cameras):
        verdict = actors_look(RULE, setup, cameras, scored_camera(job.camera, str(job.case.camera or "")))
        if verdict is not None:
            raise Screened(verdict)

    try:
        preflight(cfg, check_space=False, load=False, screen=screen)
    except Screened as exc:
        return exc.verdict
    return None


def test_a_drawn_points_plain_settings_and_first_look_equal_the_composed_configs():
    """80 random points of the wide space: the plain settings equal `settings()` of the composed config (before
    and after the generated plan's garage is handed on), and the plain first look gives what the full check gives:
    the same refusal in the same words for colliding actors, the same rejection and estimate, or the full check's
    turn when the placed actors pass."""
    from hydra.types import RunMode

    from garage_exp.run.preflight import classified_plan, hand_on, resolve_plan_path
    from garage_exp.search import space as space_mod
    from garage_exp.search.launch import CachedLaunch
    from garage_exp.search.sweep import group_levels

    outcomes = {"infeasible": 0, "rejected": 0, "passed": 0}
    with hydra_loader() as loader:
        master = loader.load_configuration("config", ["hydra/sweeper=search", "space=wide"], RunMode.MULTIRUN)
        arguments = space_mod.expand(master, ["space=wide"])
        space = space_mod.build(arguments, master, group_levels(loader))
        launch = CachedLaunch(SimpleNamespace(config_loader=loader), None, master, set(group_levels(loader)))
        rng = np.random.default_rng(7)
        for number in range(80):
            overrides = draw(space, rng, number)
            cfg = launch.compositions.compose(overrides, job=False)
            assert same(launch.plain.settings(overrides), settings(cfg)), overrides
            plan = classified_plan(resolve_plan_path(cfg.plan)).plan
            assert plan.garage  # a generated plan hands its garage on
            hand_on(cfg, plan)
            assert same(launch.plain.handed_on(overrides, plan), settings(cfg)), overrides
            try:
                expected = full_check(cfg)
            except Infeasible as exc:
                with pytest.raises(Infeasible) as err:
                    first_look(launch.plain, overrides, RULE)
                assert str(err.value) == str(exc) and err.value.where == exc.where
                outcomes["infeasible"] += 1
                continue
            got = first_look(launch.plain, overrides, RULE)
            if expected is None:
                assert got is None
                outcomes["passed"] += 1
            else:
                assert got is not None and (got.ok, got.why, got.best) == (expected.ok, expected.why, expected.best)
                outcomes["rejected"] += 1
    print(outcomes)
    assert all(n >= 5 for n in outcomes.values()), outcomes  # each way a draw goes, several times


def test_what_plain_data_cannot_make_exactly_is_left_to_the_full_check():
    """A changed key that a resolver or a concatenation reads, or a key the config lacks: None (the full check
    composes the draw). A plain reference to a changed key reads its new value, converted by its own node."""
    config = OmegaConf.structured(Config)
    base = Base.of(config)
    assert base.plain.occluder.width == 1.0 and base.plain.occluder.height == 2.5
    moved = base.with_values({("occluder", "length"): 3})
    assert same(moved.occluder.width, 3.0) and same(moved.occluder.length, 3.0) and moved.garage.ceiling == 2.5
    assert base.with_values({("seed",): 4}).seed == 4 and base.plain.seed == 1  # the base is left as it was
    assert base.with_values({("garage", "ceiling"): 3.0}) is None  # `label` concatenates it
    assert base.with_values({("occluder", "depth"): 1.0}) is None  # no such key
    chained = Base.of(OmegaConf.create({"a": 1.0, "b": "${a}", "c": "${b}"}))
    assert chained.with_values({("a",): 2.0}) is None  # c reads b, which reads a: left to OmegaConf
    assert base.with_values({("occluder",): 1.0}) is None  # a container, not a value


def test_a_search_with_the_plain_first_look_tells_every_draw_as_the_full_check_does(tmp_path):
    """Two random searches of the wide space with one seed, one checking each draw on its composed config alone,
    the other looking first from plain data (as the sweeper's does): the same draws, each told the same (state,
    rejection and estimate, infeasible refusal), the same ones launched; and most draws never composed."""
    from hydra.types import RunMode

    from garage_exp.search import space as space_mod
    from garage_exp.search import study as study_mod
    from garage_exp.search.launch import CachedLaunch
    from garage_exp.search.loop import SearchLoop
    from garage_exp.search.sweep import group_levels

    def run(name: str, plain: bool):
        launched, composed = [], []
        launch = recording_launch(launched)

        store = f"search.storage=sqlite:///{tmp_path / (name + '.db')}"
        with hydra_loader() as loader:
            command = ["space=wide", "plan.seed=int(interval(0,3))", "search.sampler=random", store,
                       "tracking.uri=sqlite:///nowhere.db"]
            master = loader.load_configuration("config", ["hydra/sweeper=search", *command], RunMode.MULTIRUN)
            arguments = space_mod.expand(master, command)
            space_mod.settle(master, arguments)
            space = space_mod.build([a for a in arguments if not a.startswith("search.")], master,
                                    group_levels(loader))
            cached = CachedLaunch(SimpleNamespace(config_loader=loader), None, master, set(group_levels(loader)))

            def compose(overrides):
                composed.append(overrides)
                return cached.compose(overrides)

            study = study_mod.open_study(master.search, name, 0, space.params)
            SearchLoop(master.search, space, study, launch, 12, compose=compose,
                       plain=cached.plain if plain else None).run()
        told = [(t.number, t.state, t.user_attrs.get("rejected"), t.user_attrs.get("require_estimate"),
                 t.user_attrs.get("placement"), t.params) for t in study.get_trials()]
        return told, launched, composed, len(cached.plain.bases)

    full, full_launched, full_composed, _ = run("full", plain=False)
    plain, plain_launched, plain_composed, bases = run("plain", plain=True)
    assert plain == full and plain_launched == full_launched
    infeasible = sum(1 for t in full if t[4])  # told without a launch, counted in the budget
    assert infeasible and any(t[2] for t in full) and len(full_launched) + infeasible == 12
    assert len(full_composed) == len(full)  # the full check composes every draw; the plain look, those it passes
    assert len(plain_composed) < len(full) / 2
    assert bases == 2  # the fixed overrides composed, then with the store a resolver reads: once each
