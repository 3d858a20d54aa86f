"""The archive of failure kinds (issue 39, item 1; garage_exp/search/archive.py): descriptors measured from a
frame table and a picture, cells, elites replaced only by harder trials, the archive sampler's asks (seeded by
the trial, resumable, distinct within a batch), suites drawn across cells, and the command line end to end with
a few tiny trials whose archive.csv rerun commands reproduce their trials' frame tables."""

from __future__ import annotations

import math

import numpy as np
import optuna
import pandas as pd
import pytest
from conftest import require, rerun_elite, run_app, run_module
from omegaconf import OmegaConf
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.trial import TrialState, create_trial
from PIL import Image
from ribs.archives import GridArchive
from scipy import stats

from garage_exp.search import archive
from garage_exp.search.schema import SearchConf


# The tests' own cells (3 x 4 x 3 x 2 = 72), so that they do not follow the shipped edges.
DESCRIPTORS = [{"source": "kind", "values": ["car", "adult", "child"]},
               {"source": "luminance", "edges": [0.0, 0.12, 0.2, 0.3, 1.0]},
               {"source": "distance", "edges": [0.0, 6.0, 10.0, 100.0]},
               {"source": "visible", "edges": [0.0, 0.9, 1.0]}]


def search_conf(**kw):
    conf = OmegaConf.merge(OmegaConf.structured(SearchConf), {"descriptors": DESCRIPTORS})
    for key, value in kw.items():
        OmegaConf.update(conf, key, value, merge=False)
    return conf


def row(**kw) -> dict:
    base = {"shot": 0, "camera": "front", "target": "target_black", "distance": 9.0, "visible_fraction": 1.0,
            "box_height": 60, "truncation": 0.0, "composite": 0.5}
    return {**base, **kw}


def test_descriptors_are_measured_at_the_first_fair_frame_of_the_table_and_from_the_picture(tmp_path):
    frame = tmp_path / "hardest.png"
    Image.fromarray(np.full((20, 30, 3), 64, np.uint8)).save(frame)  # luma 64/255
    table = pd.DataFrame([
        row(shot=0, target="child_walking", target_kind="person", distance=12.0, visible_fraction=0.2),  # hidden
        row(shot=1, target="child_walking", target_kind="person", distance=8.5, visible_fraction=0.7),  # first fair
        row(shot=2, target="child_walking", target_kind="person", distance=6.0, visible_fraction=1.0)])
    search = search_conf()
    got = archive.measure(table, tmp_path, str(frame), search)
    assert got["kind"] == "child" and got["distance"] == 8.5 and got["visible"] == 0.7
    assert got["luminance"] == pytest.approx(64 / 255, abs=1e-6)
    adult = table.assign(target="walker")
    assert archive.measure(adult, tmp_path, str(frame), search)["kind"] == "adult"
    cars = table.drop(columns="target_kind")  # a vehicle-only table has no target_kind column
    assert archive.measure(cars, tmp_path, str(frame), search)["kind"] == "car"
    # only the first camera's frames are scored, as the search scores them: the table's first camera, whichever
    rear = pd.DataFrame([row(camera="rear", distance=3.0)])
    other = pd.concat([rear, table.assign(camera="front")])
    assert archive.measure(other, tmp_path, str(frame), search)["distance"] == 3.0
    # and another camera's fair frame before the first camera's first fair one is not it
    between = pd.concat([table.iloc[:1], rear, table.iloc[1:]])
    assert archive.measure(between, tmp_path, str(frame), search)["distance"] == 8.5
    # no fair frame: no descriptors (the trial is pruned as infeasible, never placed in a cell)
    assert archive.measure(table.assign(visible_fraction=0.1), tmp_path, str(frame), search) is None
    assert math.isnan(archive.measure(table, tmp_path, None, search)["luminance"])


def test_cells_bin_categories_by_value_and_numbers_by_edges():
    grid = archive.Grid([{"source": "kind", "values": ["car", "adult", "child"]},
                         {"source": "distance", "edges": [0.0, 6.0, 10.0, 100.0]}])
    assert grid.dims == [3, 3]
    assert grid.index({"kind": "adult", "distance": 5.9}) == (1, 0)
    assert grid.index({"kind": "child", "distance": 6.0}) == (2, 1)  # an inner edge opens the upper bin
    assert grid.index({"kind": "car", "distance": 250.0}) == (0, 2)  # past the last edge: the last bin
    assert grid.index({"kind": "car", "distance": -1.0}) == (0, 0)
    assert grid.index({"kind": "truck", "distance": 5.0}) is None  # not one of the category's values
    assert grid.index({"kind": "car", "distance": math.nan}) is None
    assert grid.name((2, 1)) == "child | 6-10"


def test_the_occluder_is_read_at_the_first_fair_frame_and_unlisted_kinds_join_the_merged_cell(tmp_path):
    table = pd.DataFrame([row(shot=0, visible_fraction=0.2, occluder="pillar"),  # hidden: not fair
                          row(shot=1, visible_fraction=0.7, occluder="vehicle"),  # first fair
                          row(shot=2, visible_fraction=1.0, occluder="none")])
    search = OmegaConf.merge(OmegaConf.structured(SearchConf), {"descriptors": [
        {"source": "occluder", "values": ["pillar", "vehicle", "none"],
         "merge": {"structure": "pillar", "person": "vehicle"}}]})
    assert archive.measure(table, tmp_path, None, search) == {"occluder": "vehicle"}
    assert archive.measure(table.drop(columns="occluder"), tmp_path, None, search) == {"occluder": ""}  # old table
    grid = archive.Grid(search.descriptors)
    assert [grid.index({"occluder": v}) for v in ("pillar", "vehicle", "none", "structure", "person", "")] == \
        [(0,), (1,), (2,), (0,), (1,), None]  # merged into their cells; a value neither listed nor merged: none
    assert archive.Grid([{"source": "occluder", "values": ["pillar", "none"]}]).index({"occluder": "person"}) is None
    # the shipped cells: kind x occluder x distance x visible, 81, every category of what hides it placed
    shipped = archive.Grid(OmegaConf.structured(SearchConf).descriptors)
    assert [d.source for d in shipped.descriptors] == ["kind", "occluder", "distance", "visible"]
    assert shipped.dims == [3, 3, 3, 3]
    assert shipped.index({"kind": "car", "occluder": "structure", "distance": 20.0, "visible": 0.55}) == (0, 0, 2, 0)
    archive.check_descriptors(OmegaConf.structured(SearchConf).descriptors)


def trial(number: int, difficulty: float, descriptors: dict | None, params: dict | None = None, x=None):
    params = params if params is not None else {"a": 0.5}
    return create_trial(state=TrialState.COMPLETE, values=[difficulty], params=params,
                        distributions={k: FloatDistribution(0.0, 1.0) for k in params},
                        user_attrs={"descriptors": descriptors, "overrides": [f"a={params.get('a')}"]},
                        system_attrs={archive.X_ATTR: x} if x is not None else {})


def numbered(trials: list) -> list:
    """The trials as a study numbers them (0, 1, ... in the order given)."""
    study = optuna.create_study(direction="maximize")
    study.add_trials(trials)
    return study.get_trials(deepcopy=False)


def cell(kind: str, distance: float = 5.0, luminance: float = 0.1, visible: float = 1.0) -> dict:
    return {"kind": kind, "distance": distance, "luminance": luminance, "visible": visible}


def test_a_cells_elite_is_replaced_only_by_a_harder_trial_and_ribs_keeps_the_same_elites():
    search = search_conf()
    # each trial at its own point (x = number / 10) but 6, another sampler's (its point from its parameters)
    made = [(0.5, cell("car")), (0.4, cell("car")), (0.5, cell("car")),  # 0 stays: 2 is no harder
            (0.6, cell("adult")), (0.7, cell("adult")), (0.65, cell("adult")),
            (0.3, cell("child", distance=8.0)), (0.9, None)]  # 7: no descriptors
    trials = numbered([trial(k, d, c, {"a": 0.25} if k == 6 else None, x=None if k == 6 else [k / 10])
                       for k, (d, c) in enumerate(made)])
    grid = archive.Grid(search.descriptors)
    elites = archive.elite_trials(trials, grid)
    assert {c: t.number for c, t in elites.items()} == {(0, 0, 0, 1): 0, (1, 0, 0, 1): 4, (2, 0, 1, 1): 6}
    numbers = archive.summary(trials, search)
    assert numbers == {"archive_cells": 72, "archive_filled": 3, "archive_failure_cells": 1,
                       "archive_coverage": pytest.approx(1 / 72), "archive_qd_score": pytest.approx(1.5)}
    ribs = archive.ribs_archive(trials, grid, {"a": FloatDistribution(0.0, 1.0)}, seed=0)
    assert held(ribs) == {(0, 0, 0, 1): ([0.0], 0.5), (1, 0, 0, 1): ([0.4], 0.7), (2, 0, 1, 1): ([0.25], 0.3)}
    # ribs' own rule, fed every trial in turn, keeps the same elites (a tie keeps the earlier, as elite_trials)
    every = GridArchive(solution_dim=1, dims=grid.dims, ranges=[(0, n) for n in grid.dims], seed=0)
    for t in trials[:7]:
        x = t.system_attrs.get(archive.X_ATTR, [t.params["a"]])
        every.add([x], t.values, [np.asarray(grid.index(t.user_attrs["descriptors"])) + 0.5])
    assert held(every) == held(ribs)
    table = archive.archive_table(trials, search)
    assert list(table.trial) == [0, 4, 6] and list(table.failure) == [False, True, False]
    assert table.rerun[0] == "python -m garage_exp a=0.5" and table.cell[0] == "car | 0-0.12 | 0-6 | 0.9-1"


def held(ribs) -> dict:
    """A ribs archive's cells: grid index -> (solution, objective)."""
    data = ribs.data()
    return {tuple(int(i) for i in ribs.int_to_grid_index(k[None])[0]): (np.round(x, 9).tolist(), round(float(v), 9))
            for k, x, v in zip(data["index"], data["solution"], data["objective"])}


def test_the_space_maps_to_the_unit_cube_and_back():
    params = {"case": CategoricalDistribution(["1", "2", "3", "pedestrian"]), "seed": IntDistribution(0, 9999),
              "light.intensity": FloatDistribution(0.1, 1.0), "far": FloatDistribution(1.0, 100.0, log=True)}
    assert archive.decode([0.0, 0.0, 0.0, 0.0], params) == {"case": "1", "seed": 0, "light.intensity": 0.1,
                                                            "far": pytest.approx(1.0)}
    values = archive.decode([0.6, 1.0, 0.5, 0.5], params)
    assert values["case"] == "3" and values["seed"] == 9999 and values["light.intensity"] == pytest.approx(0.55)
    assert values["far"] == pytest.approx(10.0)
    assert archive.decode(archive.encode(values, params), params) == pytest.approx(values)  # a choice: its bin's middle


def test_the_sampler_mutates_elites_after_startup_seeded_by_the_trial_number():
    params = {"a": FloatDistribution(0.0, 1.0), "b": FloatDistribution(0.0, 1.0)}
    search = search_conf()
    sampler = archive.ArchiveSampler(params, search.descriptors, seed=3, startup=2, sigma=0.05)
    elite = numbered([trial(0, 0.8, cell("adult"), {"a": 0.9, "b": 0.1}, x=[0.9, 0.1])])[0]
    assert archive.ribs_archive([elite], sampler.grid, params, 0).stats.num_elites == 1
    # after the startup trials, every ask is the one elite plus the emitter's noise (sigma 0.05)
    asked = np.array([sampler.ask_point([elite], n) for n in range(2, 12)])
    assert np.abs(asked - [0.9, 0.1]).max() < 0.3 and len({tuple(p) for p in asked}) == len(asked)
    # the same trial number on the same archive asks the same point: a resume, another worker
    again = archive.ArchiveSampler(params, search.descriptors, seed=3, startup=2, sigma=0.05)
    assert np.array_equal(again.ask_point([elite], 5), asked[3])
    # the startup trials are uniform, whatever the archive holds: the same draws as on an empty archive, and
    # uniform on [0, 1] by a Kolmogorov-Smirnov test of each coordinate over 200 (seeded) draws
    startup = archive.ArchiveSampler(params, search.descriptors, seed=3, startup=200, sigma=0.05)
    first = np.array([startup.ask_point([elite], n) for n in range(200)])
    assert np.array_equal(first, [startup.ask_point([], n) for n in range(200)])
    assert min(stats.kstest(first[:, k], "uniform").pvalue for k in range(2)) > 0.01


def test_the_sparse_emitter_redraws_one_to_three_factors_of_an_elite_and_keeps_the_rest():
    params = {k: FloatDistribution(0.0, 1.0) for k in "abcdefgh"}
    search = search_conf()
    sampler = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1, emitter="sparse")
    parents = [[0.1] * 8, [0.9] * 8]
    elites = numbered([trial(0, 0.8, cell("adult"), x=parents[0]), trial(1, 0.8, cell("car"), x=parents[1])])
    asked = np.array([sampler.ask_point(elites, n) for n in range(2, 402)])
    parent = [int(np.sum(p == 0.9) > np.sum(p == 0.1)) for p in asked]  # the one it keeps most factors of
    moved = [int(np.sum(p != parents[k])) for p, k in zip(asked, parent)]
    assert set(moved) == {1, 2, 3}  # never 0 (a copy) nor more than 3: every other factor is its parent's
    assert 0.4 < np.mean(parent) < 0.6  # either elite, uniformly
    changed = asked[(asked != 0.1) & (asked != 0.9)]  # the redrawn factors: anywhere in the space
    assert stats.kstest(changed, "uniform").pvalue > 0.01
    again = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1, emitter="sparse")
    assert np.array_equal(again.ask_point(elites, 7), asked[5])  # seeded by the trial's number


def driven_study(n: int = 60) -> list:
    """Trials whose cells follow their factors as a wide space's do: the distance bin from factor b, the luminance
    bin from factor d (with a little of e), the kind and the visible bin from nothing (every trial a car, whole)."""
    rng = np.random.default_rng(0)
    made = []
    for k in range(n):
        x = rng.uniform(size=6)
        made.append(trial(k, float(x[0]), cell("car", distance=4.0 + 16.0 * x[1], luminance=0.9 * x[3] + 0.1 * x[4]),
                          x=list(x)))
    return numbered(made)


def test_the_directed_emitter_learns_each_descriptors_drivers_and_moves_an_elite_along_one():
    params = {k: FloatDistribution(0.0, 1.0) for k in "abcdef"}
    search = search_conf()
    grid = archive.Grid(search.descriptors)
    trials = driven_study()
    # luminance: d (and e, its lesser driver, only when within half of d's share), distance: b; kind and visible,
    # which every trial shares a bin of, have none
    assert [sorted(map(int, a)) for a in archive.drivers(trials, grid, params)] == [[3], [1]]
    assert archive.drivers(trials[:archive.DIRECTED_MIN - 1], grid, params) is None  # too few to learn from
    sampler = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1, emitter="directed")
    elites = {tuple(t.system_attrs[archive.X_ATTR]) for t in archive.elite_trials(trials, grid).values()}
    asked = np.array([sampler.ask_point(trials, n) for n in range(60, 460)])
    moved = []
    for x in asked:  # each offspring is an elite with exactly one axis' drivers redrawn
        parent = min(elites, key=lambda e: int(np.sum(np.asarray(e) != x)))
        moved.append(tuple(np.flatnonzero(np.asarray(parent) != x)))
    assert set(moved) == {(1,), (3,)} and 0.4 < moved.count((1,)) / len(moved) < 0.6
    assert stats.kstest(asked[[m == (1,) for m in moved], 1], "uniform").pvalue > 0.01  # redrawn anywhere
    assert np.array_equal(sampler.ask_point(trials, 67), asked[7])  # seeded by the trial's number
    # with curiosity choosing the parent, the same move; before the drivers are learnt, a Gaussian step
    curious = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1, emitter="directed",
                                     parents="curiosity", sigma=0.01)
    x, parent = curious.ask(trials, 70)
    assert int(np.sum(x != np.asarray(trials[parent].system_attrs[archive.X_ATTR]))) == 1
    x, parent = curious.ask(trials[:5], 70)
    assert np.all(np.abs(x - np.asarray(trials[parent].system_attrs[archive.X_ATTR])) < 0.06)
    assert int(np.sum(x != np.asarray(trials[parent].system_attrs[archive.X_ATTR]))) == 6


def offspring(number: int, parent: int, difficulty: float | None, descriptors: dict | None = None, x=None):
    """A finished trial mutated from trial `parent`: complete with `difficulty`, or pruned (None: infeasible)."""
    if difficulty is None:
        return create_trial(state=TrialState.PRUNED, params={"a": 0.5},
                            distributions={"a": FloatDistribution(0.0, 1.0)},
                            system_attrs={archive.PARENT_ATTR: parent})
    made = trial(number, difficulty, descriptors, x=x)
    made.system_attrs[archive.PARENT_ATTR] = parent
    return made


def test_curiosity_scores_a_parent_by_the_offspring_that_entered_the_archive():
    search = search_conf()
    grid = archive.Grid(search.descriptors)
    trials = numbered([trial(0, 0.5, cell("car"), x=[0.1]), trial(1, 0.5, cell("adult"), x=[0.9]),
                       offspring(2, 0, 0.7, cell("child")),  # a new cell: +1 to 0
                       offspring(3, 0, 0.8, cell("car")),  # harder than car's elite: +1
                       offspring(4, 1, 0.2, cell("car")),  # easier than car's elite: -0.5 to 1
                       offspring(5, 1, None),  # infeasible: -0.5
                       offspring(6, 2, 0.9, cell("child"))])  # an offspring's offspring: +1 to 2
    assert archive.curiosity(trials, grid) == {0: 2.0, 1: -1.0, 2: 1.0}


def test_curiosity_draws_the_productive_elite_more_often_and_records_each_offspring_s_parent():
    params = {"a": FloatDistribution(0.0, 1.0)}
    search = search_conf()
    made = [trial(0, 0.5, cell("car"), x=[0.1]), trial(1, 0.5, cell("adult"), x=[0.9])]
    made += [offspring(k, 0, 0.6 + k / 100, cell("child")) for k in range(2, 6)]  # 0's: each enters the archive
    made += [offspring(k, 1, None) for k in range(6, 10)]  # 1's: infeasible
    trials = numbered(made)
    sampler = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1, parents="curiosity",
                                     sigma=0.01)
    asked = [sampler.ask(trials, n) for n in range(10, 410)]
    parents = [p for _, p in asked]
    # the elites 0 (score 4: weight 5), 1 (-2: weight 0.1) and 5 (the child cell's, 0: weight 1): 5 / 6.1 for 0
    assert 0.75 < parents.count(0) / 400 < 0.89 and parents.count(1) / 400 < 0.04 and 5 in parents
    assert all(abs(x[0] - 0.1) < 0.05 for x, p in asked if p == 0)  # a Gaussian step (sigma 0.01) from its point
    assert sampler.ask(trials, 17)[1] == parents[7]  # seeded by the trial's number
    study = optuna.create_study(direction="maximize", sampler=archive.ArchiveSampler(
        params, search.descriptors, seed=0, startup=0, parents="curiosity"))
    study.add_trials(made[:2])
    child = study.ask(fixed_distributions=params)
    assert study._storage.get_trial(child._trial_id).system_attrs[archive.PARENT_ATTR] in (0, 1)


def test_curiositys_parent_takes_an_iso_line_step_towards_another_elite():
    """parents=curiosity with emitter=iso_line: the drawn parent plus Gaussian noise plus a step along the line to
    another elite drawn uniformly. With the two elites at 0.3 and 0.7 and a tiny Gaussian spread, about half the
    offspring of 0 stay at 0.3 (their other end was 0 itself) and the rest spread along the line by LINE_SIGMA of
    the 0.4 between them, never by the Gaussian step's 0.001 alone."""
    params = {"a": FloatDistribution(0.0, 1.0)}
    search = search_conf()
    made = [trial(0, 0.5, cell("car"), x=[0.3]), trial(1, 0.5, cell("adult"), x=[0.7])]
    trials = numbered(made)
    sampler = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1, parents="curiosity",
                                     sigma=0.001, emitter="iso_line")
    asked = [sampler.ask(trials, n) for n in range(10, 810)]
    from_0 = np.array([x[0] for x, p in asked if p == 0])
    assert len(from_0) > 200 and {p for _, p in asked} == {0, 1}
    moved = np.abs(from_0 - 0.3) > 0.01
    assert 0.3 < moved.mean() < 0.6
    assert np.std(from_0[moved] - 0.3) == pytest.approx(0.4 * archive.LINE_SIGMA, rel=0.25)
    assert np.array_equal(sampler.ask(trials, 17)[0], asked[7][0])  # seeded by the trial's number


def test_an_elite_at_an_end_of_the_space_sends_its_offspring_elsewhere_too():
    """Offspring past an end wrap round a choice's values and reflect off a number's ends: an elite at the last
    case and the first light (x = 1, 0) keeps about a fifth of its offspring in its own case and light, where
    clipping at the bounds kept nine in ten; no offspring piles on a number's end."""
    params = {"case": CategoricalDistribution(["1", "2", "3", "pedestrian"]),
              "light": CategoricalDistribution(["bright", "clear", "moderate", "dim"]),
              "gap": FloatDistribution(0.0, 1.0)}
    search = search_conf()
    sampler = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=0, sigma=0.15)
    elite = numbered([trial(0, 0.9, cell("adult"), x=[1.0, 0.0, 1.0])])[0]  # pedestrian, bright, gap 1.0
    asked = np.array([sampler.ask_point([elite], n) for n in range(1, 301)])
    assert np.all((asked >= 0) & (asked <= 1))
    home = [archive.decode(x, params) for x in asked]
    share = np.mean([v["case"] == "pedestrian" and v["light"] == "bright" for v in home])
    assert 0.1 < share < 0.35  # wrapped: 0.45 x 0.45 = 0.2 (clipped: 0.95 x 0.95 = 0.9)
    assert np.mean(asked[:, 2] == 1.0) == 0 and asked[:, 2].min() < 0.75  # reflected, spread below the end
    assert archive.fold([1.1, -0.1, 1.1], params) == pytest.approx([0.1, 0.9, 0.9])


def test_a_batch_asked_before_any_tell_is_distinct_and_its_points_are_kept_on_the_trials():
    params = {"a": FloatDistribution(0.0, 1.0)}
    search = search_conf()
    study = optuna.create_study(direction="maximize",
                                sampler=archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1))
    first = study.ask(fixed_distributions=params)
    first.set_user_attr("descriptors", cell("car"))
    study.tell(first, 0.7)
    batch = [study.ask(fixed_distributions=params) for _ in range(3)]
    values = [t.params["a"] for t in batch]
    assert len(set(values)) == 3
    for t in batch:
        kept = study._storage.get_trial(t._trial_id).system_attrs[archive.X_ATTR]
        assert archive.decode(kept, params)["a"] == t.params["a"]


def test_an_archive_suite_takes_one_scenario_per_cell_of_a_band():
    from garage_exp.search.suite import members

    study = optuna.create_study(direction="maximize")
    study.add_trials([trial(0, 0.9, cell("car")), trial(1, 0.95, cell("car")), trial(2, 0.85, cell("car")),
                      trial(3, 0.8, cell("child")), trial(4, 0.7, cell("adult", distance=20.0))])
    band = {"hard": [0.0, 0.4]}
    spread = members(study, search_conf(sampler="archive", **{"suite.per_band": 3, "suite.bands": band}))
    assert sorted(t.number for t in spread["hard"]) == [1, 3, 4]  # the car cell's hardest, and the two others
    plain = members(study, search_conf(sampler="tpe", **{"suite.per_band": 3, "suite.bands": band}))
    assert len({archive.Grid(DESCRIPTORS).index(t.user_attrs["descriptors"])
                for t in plain["hard"]}) < 3  # without the archive, a band may take three scenarios of one cell


# A few tiny trials (2 frames at 320x240 on plan=tiny); the fairness rule loosened for the small picture.
TINY = ["-m", "hydra/sweeper=search", "search.sampler=archive", "search.trials=4", "search.startup=2",
        "search.batch=2", "search.min_box=10", "search.max_truncation=1.0", "plan=tiny", "camera.width=320",
        "camera.height=240", "palette.target_colours=[black]", "case.motion.start=5", "case.motion.end=4",
        "case.motion.step=1", "light=choice(bright,dim)", "case.actors.target.distance=interval(4.0,6.0)",
        "search.descriptors=[{source:kind,values:[car,adult,child]},{source:distance,edges:[0,7,7.3,100]}]"]


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_the_archive_search_writes_its_archive_and_each_elites_rerun_reproduces_its_trial(tmp_path):
    require("vulkan", "vehicles", "models")
    from garage_exp.tracking import runs as tracking

    stores = [f"search.storage=sqlite:///{tmp_path / 'optuna.db'}", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"]
    r = run_app([*TINY, *stores], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    out = tmp_path / "sweep" / "search"
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    study = optuna.load_study(study_name=optuna.get_all_study_names(storage)[0], storage=storage)
    done = study.get_trials(states=(TrialState.COMPLETE,))
    assert len(study.trials) == 4 and done
    assert all(set(t.user_attrs["descriptors"]) == {"kind", "distance"} for t in done)
    assert all(archive.X_ATTR in t.system_attrs for t in study.trials)  # every trial asked by the archive
    table = pd.read_csv(out / "archive.csv")
    assert len(table) == len(set(table.cell)) >= 1 and set(table.kind) == {"car"}
    best_per_cell = {}
    grid = archive.Grid(OmegaConf.create({"d": [{"source": "kind", "values": ["car", "adult", "child"]},
                                                {"source": "distance", "edges": [0, 7, 7.3, 100]}]}).d)
    for t in done:
        c = grid.name(grid.index(t.user_attrs["descriptors"]))
        best_per_cell[c] = max(best_per_cell.get(c, 0.0), t.values[0])
    assert dict(zip(table.cell, table.difficulty)) == pytest.approx(best_per_cell)  # each cell's hardest
    assert (out / "archive.png").stat().st_size > 0
    mlc = tracking.client(f"sqlite:///{tmp_path / 'mlflow.db'}")
    exp = mlc.get_experiment_by_name("garage_exp")
    parent = next(run for run in mlc.search_runs([exp.experiment_id]) if run.data.tags.get("sweep") == "parent")
    assert parent.data.metrics["archive_cells"] == 9
    assert parent.data.metrics["archive_filled"] == len(table)
    assert parent.data.metrics["archive_failure_cells"] == int(table.failure.sum())
    assert parent.data.metrics["archive_qd_score"] == pytest.approx(table.difficulty.sum(), abs=1e-5)
    assert "archive:" in r.stdout
    # the report shows and links them (issue 47, item 8: it neither mentioned nor linked them), and the analysis
    # command writes them for the study again
    report = (out / "search_report.md").read_text()
    assert "## The archive of failure kinds" in report and "[archive.csv](archive.csv)" in report
    assert f"{int(table.failure.sum())} of 9 cells hold a hard-and-fair failure" in report
    assert "![the archive: difficulty of each cell's elite](archive.png)" in report
    again = run_module("garage_exp.report.search_analysis", ["--storage", storage, "-o", str(tmp_path / "again")],
                       tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "again" / "archive.csv"), table)
    assert (tmp_path / "again" / "archive.png").stat().st_size > 0
    for _, elite in table.iterrows():  # each elite's rerun command gives its trial's frame table
        theirs = pd.read_csv(f"{study.trials[int(elite.trial)].user_attrs['output_dir']}/frames.csv")
        pd.testing.assert_frame_equal(rerun_elite(elite, tmp_path), theirs)


def surrogate_cell(x) -> dict:
    """The cell a point of a..f lands in: its kind set by a, its distance by b, its luminance by c."""
    kind = "car" if x[0] < 1 / 3 else ("adult" if x[0] < 2 / 3 else "child")
    return cell(kind, distance=2.0 + 20.0 * x[1], luminance=0.4 * x[2])


def surrogate_study(n: int, seed: int = 0) -> list:
    """n trials at uniform points of a..f, each in surrogate_cell(x) and failing (difficulty 0.8) when d > 0.7;
    every third one rejected (pruned, no cell)."""
    rng = np.random.default_rng(seed)
    made = []
    for k in range(n):
        x = rng.uniform(size=6)
        values = dict(zip("abcdef", map(float, x)))
        if k % 3 == 2:
            made.append(create_trial(state=TrialState.PRUNED, params=values,
                                     distributions={c: FloatDistribution(0.0, 1.0) for c in "abcdef"},
                                     user_attrs={"rejected": "too far"}, system_attrs={archive.X_ATTR: list(x)}))
            continue
        made.append(trial(k, 0.8 if x[3] > 0.7 else 0.2, surrogate_cell(x), params=values, x=list(x)))
    return numbered(made)


def test_the_surrogate_emitter_proposes_draws_predicted_to_fail_in_cells_without_a_failure():
    """search.archive.emitter=surrogate (search/surrogate.py): a forest fit on the study predicts each candidate's
    cell and verdict; the ask is the candidate expected to add the most failure cells not yet found. On a study
    of 120 trials whose failures need d > 0.7 and which holds failures in about half of its 36 cells, the asks
    fail in a cell without a failure far more often than uniform draws do."""
    from garage_exp.search import surrogate

    params = {k: FloatDistribution(0.0, 1.0) for k in "abcdef"}
    search = search_conf()
    grid = archive.Grid(search.descriptors)
    trials = surrogate_study(120)
    held = surrogate.open_cells(trials, grid, 0.6)
    reachable = {grid.index(surrogate_cell(x)) for x in np.random.default_rng(1).uniform(size=(4000, 6))}
    found = [c for c in reachable if not held[np.ravel_multi_index(c, grid.dims)]]
    assert len(reachable) == 36 and 8 <= len(found) <= 28

    def new_failure(x) -> bool:
        return x[3] > 0.7 and held[np.ravel_multi_index(grid.index(surrogate_cell(x)), grid.dims)]

    sampler = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1, emitter="surrogate",
                                     failure=0.6)
    asked = [sampler.ask(trials, n) for n in range(120, 160)]
    rate = np.mean([new_failure(x) for x, _ in asked])
    uniform = np.mean([new_failure(x) for x in np.random.default_rng(2).uniform(size=(2000, 6))])
    assert uniform < 0.25 and rate > 0.45
    assert sampler._surrogate[0] == 120 // surrogate.REFIT * surrogate.REFIT  # fit on the first k * REFIT
    # a Gaussian offspring names its parent, an elite of the study; a uniform draw none
    elites = {t.number for t in archive.elite_trials(trials, grid).values()}
    assert all(p is None or p in elites for _, p in asked)
    # seeded by the trial's number, and the same from a fresh sampler (a resume, another worker)
    again = archive.ArchiveSampler(params, search.descriptors, seed=0, startup=1, emitter="surrogate")
    assert np.array_equal(again.ask(trials, 125)[0], asked[5][0])
    # the expectation: a point that fails in an open cell against the same point passing, or in a found cell
    model = sampler._surrogate[1]
    open_x = next(x for x in np.random.default_rng(3).uniform(size=(4000, 6)) if new_failure(x))
    done_x = next(x for x in np.random.default_rng(4).uniform(size=(4000, 6))
                  if x[3] > 0.9 and not held[np.ravel_multi_index(grid.index(surrogate_cell(x)), grid.dims)])
    passing = np.array([*open_x[:3], 0.2, *open_x[4:]])
    got = model.expected(np.array([open_x, passing, done_x]), held)
    assert got[0] > 2 * max(got[1], got[2])
    # too few trials with a cell to learn from (none yet fit on, or under MIN_CELLS): a Gaussian step from an elite
    for few in (3, 24, 60):
        x, parent = sampler.ask(trials[:few], few)
        assert parent in {t.number for t in archive.elite_trials(trials[:few], grid).values()}
    assert sampler._surrogate == (50, None)
    assert np.all(np.abs(x - np.asarray(trials[parent].system_attrs[archive.X_ATTR])) < 0.9)


def test_the_surrogate_emitter_is_accepted_by_the_searchs_check_and_a_misspelt_one_named():
    from garage_exp.core.errors import GarageError
    from garage_exp.search.study import check_search

    search = search_conf(sampler="archive", objective="difficulty")
    OmegaConf.update(search, "archive.emitter", "surrogate")
    check_search(search)
    OmegaConf.update(search, "archive.emitter", "surogate")
    with pytest.raises(GarageError, match="unknown emitter 'surogate'.*surrogate"):
        check_search(search)
