"""The search (garage_exp/search): its space, the trial loop and the study, with a stand-in for the job (no
rendering); the end-to-end runs are in tests/test_search_runs.py."""

import math
import multiprocessing
from dataclasses import dataclass
from types import SimpleNamespace

import optuna
import pandas as pd
import pytest
from conftest import ROOT, compose_cfg
from optuna.trial import TrialState

from garage_exp.results import table as results
from garage_exp.core.errors import GarageError
from garage_exp.search import space as space_mod
from garage_exp.search import study as study_mod
from garage_exp.search.loop import SearchLoop, outcome


def levels() -> dict[str, list[str]]:
    return {p.name: sorted(f.stem for f in p.glob("*.yaml")) for p in (ROOT / "conf").iterdir() if p.is_dir()}


@pytest.fixture(scope="module")
def cfg():
    return compose_cfg("plan=tiny")


def test_the_override_grammar_becomes_optunas_distributions(cfg):
    space = space_mod.build(["plan=tiny", "light.intensity=interval(0.1,1.0)", "light.coverage=tag(log, interval(0.1,1))",
                             "case.actors.target.distance=range(4,10,2)", "light=choice(bright,dim)", "sensor=ideal,noisy",
                             "seed=int(interval(0,9))"], cfg, levels())
    assert space.fixed == ["plan=tiny"]
    p = space.params
    assert p["light.intensity"] == optuna.distributions.FloatDistribution(0.1, 1.0)
    assert p["light.coverage"] == optuna.distributions.FloatDistribution(0.1, 1.0, log=True)
    assert p["case.actors.target.distance"] == optuna.distributions.IntDistribution(4, 8, step=2)
    assert p["light"] == optuna.distributions.CategoricalDistribution(["bright", "dim"])
    assert p["sensor"] == optuna.distributions.CategoricalDistribution(["ideal", "noisy"])
    assert p["seed"] == optuna.distributions.IntDistribution(0, 9)
    over = space.overrides({"light.intensity": 0.123456789, "light.coverage": 0.5, "case.actors.target.distance": 6,
                            "light": "dim", "sensor": "ideal", "seed": 3})
    assert over == ["plan=tiny", "light.intensity=0.123457", "light.coverage=0.5", "case.actors.target.distance=6",
                    "light=dim", "sensor=ideal", "seed=3"]
    assert space_mod.format_value("1") == "'1'"  # a case level named 1 stays a string


@pytest.mark.parametrize("args, message", [
    (["light.intensty=interval(0.1,1)"], "the config has no key light.intensty"),
    (["light.intensity=interval(1.0,0.5)"], "the interval is empty"),
    (["light=choice(bright,dusk)"], "light has no level 'dusk'"),
    (["light=interval(0,1)"], "light is a config group"),
    (["search.trials=interval(1,5)"], "search.trials cannot be searched"),
    (["plan=tiny"], "nothing to search"),
])
def test_a_bad_space_is_one_line_naming_the_override(cfg, args, message):
    with pytest.raises(GarageError) as err:
        space_mod.build(args, cfg, levels())
    assert message in str(err.value) and "\n" not in str(err.value)


def table(**cols) -> pd.DataFrame:
    n = len(cols["composite"])
    return pd.DataFrame({"camera": ["front"] * n, **cols})


def rule(min_visible=0.5, min_box=25, max_truncation=0.5):
    return SimpleNamespace(min_visible=min_visible, min_box=min_box, max_truncation=max_truncation)


def test_only_fairly_visible_frames_count():
    t = table(composite=[0.9, 0.1, 0.0, 0.5, 0.05], visible_fraction=[1.0, 0.6, 0.2, 0.9, 0.9],
              box_height=[80, 30, 80, 20, 40], truncation=[0.0, 0.5, 0.0, 0.0, 0.7])
    fair = results.fair_summary(t, "front", rule(), threshold=0.5)
    # frame 3 is too hidden, frame 4 too small, frame 5 mostly outside the image: the two fair frames average 0.5
    assert fair["fair_frames"] == 2 and fair["fair_confidence"] == pytest.approx(0.5)
    assert fair["fair_difficulty"] == pytest.approx(0.5) and fair["fair_recall"] == pytest.approx(0.5)
    assert results.fair_summary(t, "front", rule(min_visible=0.95), 0.5)["fair_frames"] == 1
    assert results.fair_summary(t, "front", rule(max_truncation=1.0), 0.5)["fair_frames"] == 3
    hidden = results.fair_summary(t.assign(visible_fraction=0.1), "front", rule(), 0.5)
    assert hidden["fair_frames"] == 0 and math.isnan(hidden["fair_difficulty"])


def test_a_target_never_fairly_visible_is_infeasible_not_hard():
    summary = {"fair_frames": 0.0, "fair_difficulty": math.nan, "visible_fraction_mean": 0.05, "frames": 4.0,
               "difficulty": 1.0, "run_id": "r", "output_dir": "/x"}
    out = outcome(summary, "difficulty")
    assert out.state == TrialState.PRUNED and out.attrs["infeasible"] is True and out.values is None
    fine = outcome({**summary, "fair_frames": 2.0, "fair_difficulty": 0.7, "visible_fraction_mean": 0.8}, "pareto")
    assert fine.state == TrialState.COMPLETE and fine.values == [0.7, 0.8]
    failed = outcome({"error": "RuntimeError: boom"}, "difficulty")
    assert failed.state == TrialState.FAIL and "boom" in failed.attrs["error"]


# ---- the loop, with a stand-in for the job ---------------------------------------------------------------------

@dataclass
class Ret:
    return_value: object


def fake_job(overrides: list[str]) -> dict:
    """A job's summary from its overrides: dim light and far targets are hard; below 0.2 the target is hidden."""
    values = dict(o.split("=", 1) for o in overrides)
    x, y = float(values["light.intensity"]), float(values["case.actors.target.distance"])
    if values.get("fail") == "yes" or x > 0.97:
        return {"error": "RuntimeError: a stand-in crash"}
    visible = 0.0 if x < 0.2 else 0.9
    conf = max(0.0, min(1.0, x - 0.03 * y))
    return {"fair_frames": 0.0 if visible == 0 else 2.0, "fair_difficulty": 1 - conf if visible else math.nan,
            "fair_confidence": conf, "fair_recall": float(conf > 0.5), "visible_fraction_mean": visible,
            "frames": 2.0, "run_id": "run-" + values["search.trial"], "output_dir": "/nowhere"}


def fake_launch(batch, idx):
    return [Ret(fake_job(list(job))) for job in batch]


SPACE = ["plan=tiny", "light.intensity=interval(0.0,1.0)", "case.actors.target.distance=interval(3.0,12.0)"]


def search_node(tmp_path, **kw):
    cfg = compose_cfg("plan=tiny", f"search.storage=sqlite:///{tmp_path / 'optuna.db'}",
                      *(f"search.{k}={v}" for k, v in kw.items()))
    return cfg


def run_loop(tmp_path, trials: int, name: str = "s", seed: int = 0, launch=fake_launch, **kw):
    cfg = search_node(tmp_path, **kw)
    space = space_mod.build(SPACE, cfg, levels())
    study = study_mod.open_study(cfg.search, name, seed, space.params)
    SearchLoop(cfg.search, space, study, launch, trials).run()
    return study


def params_of(study):
    return [(t.number, t.params, t.state) for t in study.get_trials()]


def test_the_same_seed_gives_the_same_trials(tmp_path):
    a = run_loop(tmp_path / "a", 6)
    b = run_loop(tmp_path / "b", 6)
    assert params_of(a) == params_of(b) and len(a.trials) == 6
    c = run_loop(tmp_path / "c", 6, seed=1)
    assert params_of(c) != params_of(a)


@pytest.mark.parametrize("sampler", ["tpe", "cmaes", "random", "qmc"])
def test_every_sampler_runs_a_study(tmp_path, sampler):
    study = run_loop(tmp_path, 4, sampler=sampler)
    assert len(study.trials) == 4 and all(t.state != TrialState.RUNNING for t in study.trials)


def test_a_grid_study_visits_each_cell_once(tmp_path):
    study = run_loop(tmp_path, 9, sampler="grid", grid_levels=3)
    cells = {(t.params["light.intensity"], t.params["case.actors.target.distance"]) for t in study.trials}
    assert cells == {(x, y) for x in (0.0, 0.5, 1.0) for y in (3.0, 7.5, 12.0)}
    assert study_mod.grid_size(space_mod.build(SPACE, search_node(tmp_path), levels()).params, 3) == 9


def test_pareto_returns_difficulty_against_visible_fraction(tmp_path):
    study = run_loop(tmp_path, 6, sampler="nsga2", objective="pareto")
    assert len(study.directions) == 2 and study.best_trials
    assert all(len(t.values) == 2 for t in study.best_trials)


def test_a_resumed_study_keeps_its_trials_and_adds_the_rest(tmp_path):
    first = params_of(run_loop(tmp_path, 3))
    again = run_loop(tmp_path, 5)  # the same name and storage: the study continues
    assert params_of(again)[:3] == first and len(again.trials) == 5
    assert params_of(run_loop(tmp_path, 5)) == params_of(again)  # nothing left to do


def test_a_failed_trial_is_recorded_and_the_study_goes_on(tmp_path):
    def launch(batch, idx):
        if idx == 1:
            raise RuntimeError("the launcher lost the job")
        if idx == 2:
            return [Ret({"error": "RuntimeError: boom in frame 3"})]
        return fake_launch(batch, idx)

    study = run_loop(tmp_path, 5, launch=launch)
    states = [t.state for t in study.trials]
    assert states[1] == states[2] == TrialState.FAIL and states.count(TrialState.FAIL) >= 2
    assert "lost the job" in study.trials[1].user_attrs["error"]
    assert "boom" in study.trials[2].user_attrs["error"]
    assert len(study.trials) == 5 and study.trials[4].state in (TrialState.COMPLETE, TrialState.PRUNED)


def test_infeasible_trials_are_pruned_not_hard(tmp_path):
    study = run_loop(tmp_path, 12, sampler="random")
    pruned = [t for t in study.trials if t.state == TrialState.PRUNED]
    assert pruned and all(t.params["light.intensity"] < 0.2 and t.user_attrs["infeasible"] for t in pruned)
    assert study.best_trial.params["light.intensity"] >= 0.2  # the hardest fair one, not a hidden target


def test_a_trial_runs_with_openblas_on_one_thread_and_the_process_gets_its_threads_back(tmp_path):
    """OpenBLAS's workers spin after each product they share: in the trial loop its products stay on the loop's
    thread (loop.one_blas_thread); outside the loop the process keeps what it had."""
    from threadpoolctl import threadpool_info

    def blas_threads():
        return {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

    before, seen = blas_threads(), []

    def launch(batch, idx):
        seen.append(blas_threads())
        return fake_launch(batch, idx)

    run_loop(tmp_path, 3, launch=launch)
    assert before and len(seen) == 3 and all(set(threads.values()) == {1} for threads in seen)
    assert blas_threads() == before


def test_a_dead_workers_trial_is_failed_and_stale_trials_are_looked_for_once_a_heartbeat(tmp_path, monkeypatch):
    """A trial whose worker died (its heartbeat older than the grace period) is failed, keeping its place in the
    budget; the loop looks for such trials once a heartbeat interval and at the study's end, not at every draw."""
    import datetime

    from optuna.storages._rdb.models import TrialHeartbeatModel

    cfg = search_node(tmp_path)
    space = space_mod.build(SPACE, cfg, levels())
    study = study_mod.open_study(cfg.search, "s", 0, space.params)
    dead = study.ask(fixed_distributions=space.params)
    store = getattr(study._storage, "_backend", study._storage)  # the database under Optuna's cache
    store.record_heartbeat(dead._trial_id)
    session = store.scoped_session()
    beat = session.query(TrialHeartbeatModel).filter(TrialHeartbeatModel.trial_id == dead._trial_id).one()
    beat.heartbeat -= datetime.timedelta(seconds=study_mod.GRACE_S + 60)
    session.commit()
    looks = []
    real = optuna.storages.fail_stale_trials
    monkeypatch.setattr(optuna.storages, "fail_stale_trials", lambda s: looks.append(1) or real(s))
    SearchLoop(cfg.search, space, study, fake_launch, 6).run()
    trials = study.get_trials()
    assert trials[0].state == TrialState.FAIL and len(trials) == 6  # its place kept: five more trials
    assert len(looks) == 2  # at the first draw and at the end, the run far shorter than a heartbeat interval


def test_a_batch_of_trials_gives_what_one_at_a_time_gives(tmp_path):
    """search.batch=K asks K trials, launches them as one batch, tells K: with the random sampler the study is
    the one a batch of 1 makes (the sampler's stream is drawn in the same order), and the launcher got batches."""
    batches = []

    def launch(batch, first):
        batches.append((len(batch), first))
        return fake_launch(batch, first)

    one = run_loop(tmp_path / "one", 7, sampler="random")
    three = run_loop(tmp_path / "three", 7, sampler="random", batch=3, launch=launch)
    assert params_of(three) == params_of(one)
    assert [t.values for t in three.trials] == [t.values for t in one.trials]
    assert batches == [(3, 0), (3, 3), (1, 6)]  # the last batch holds what the budget leaves


def test_a_failing_job_in_a_batch_fails_its_trial_only(tmp_path):
    """A job that raises fails its own trial; the batch's others are told their outcomes; a TPE batch (constant
    liar) runs."""
    class Raises:
        @property
        def return_value(self):
            raise RuntimeError("boom in the job")

    def launch(batch, first):
        rets = fake_launch(batch, first)
        return [Raises() if k == 1 else r for k, r in enumerate(rets)]

    study = run_loop(tmp_path, 4, batch=4, launch=launch)
    states = [t.state for t in study.trials]
    assert states[1] == TrialState.FAIL and "boom in the job" in study.trials[1].user_attrs["error"]
    assert all(s != TrialState.RUNNING for s in states) and states.count(TrialState.FAIL) < 4
    assert study.sampler._constant_liar


def test_a_batch_with_gaps_is_numbered_by_its_trials():
    """A batch whose trial numbers have gaps (pre-screened trials) reaches a Hydra launcher as one launch per
    run of consecutive numbers, so each job's dir is its trial's number."""
    from garage_exp.search.launch import job_numbers, launch_in_runs

    calls = []

    class Launcher:
        def launch(self, batch, initial_job_idx):
            calls.append((list(batch), initial_job_idx))
            return [f"{initial_job_idx + k}:{b}" for k, b in enumerate(batch)]

    assert launch_in_runs(Launcher(), ["a", "b", "c", "d"], [4, 5, 7, 8]) == ["4:a", "5:b", "7:c", "8:d"]
    assert calls == [(["a", "b"], 4), (["c", "d"], 7)]
    assert job_numbers(3, 2) == [3, 4] and job_numbers([1, 9], 2) == [1, 9]
    with pytest.raises(ValueError):
        job_numbers([1], 2)


def test_a_long_random_search_keeps_no_trial_in_memory(tmp_path):
    """The random sampler reads no history and the loop counts trials in the database, so a random study holds
    none of its trials in this process (Optuna's cache held every one, ~5 kB each: the soak's RSS rise); a
    model-based sampler's study still keeps its history (the sampler reads it at every ask)."""
    import gc

    from optuna.trial import FrozenTrial

    def live_trials() -> int:
        gc.collect()
        return sum(isinstance(o, FrozenTrial) for o in gc.get_objects())

    # 40 trials: a cache that kept them would hold 40 (4 x the bound), as it held 120 of 120 before
    before = live_trials()
    study = run_loop(tmp_path / "random", 40, sampler="random", batch=4)
    assert live_trials() - before < 10
    assert len(study.get_trials(deepcopy=False)) == 40  # all there, in the database
    tpe = run_loop(tmp_path / "tpe", 12, sampler="tpe", startup=5)
    assert live_trials() - before >= 12 and len(tpe.trials) == 12


def _worker(path: str, trials: int) -> None:
    from pathlib import Path

    run_loop(Path(path), trials, name="shared")


def test_two_worker_processes_share_one_study(tmp_path):
    ctx = multiprocessing.get_context("spawn")
    workers = [ctx.Process(target=_worker, args=(str(tmp_path), 6)) for _ in range(2)]
    for w in workers:
        w.start()
    for w in workers:
        w.join(120)
    assert [w.exitcode for w in workers] == [0, 0]
    study = optuna.load_study(study_name="shared", storage=f"sqlite:///{tmp_path / 'optuna.db'}")
    numbers = [t.number for t in study.trials]
    assert sorted(numbers) == list(range(6))  # exactly the asked number, no number twice
    assert all(t.user_attrs.get("run_id") or t.state == TrialState.FAIL for t in study.trials)


def test_a_trial_composed_from_the_cache_equals_hydras_own_composition():
    """The search's launcher (and its check of the space: search/compose.py) composes once per combination of
    group levels and sets the values on a copy; the config a job sees is Hydra's, key for key (the same values,
    choices, overrides and dirname)."""
    from types import SimpleNamespace

    from conftest import hydra_loader
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from garage_exp.search.launch import CachedLaunch

    with hydra_loader() as loader:
        master = loader.load_configuration("config", ["hydra/sweeper=search", "plan=tiny"], RunMode.MULTIRUN)
        launch = CachedLaunch(SimpleNamespace(config_loader=loader), None, master, set(levels()))
        for trial in (["plan=tiny", "light=dim", "light.intensity=0.3", "palette.target_colours=[black]",
                       "case.actors.target.distance=5.5", "search.trial=0"],
                      ["plan=tiny", "light=bright", "light.intensity=0.7", "case='3'", "search.trial=1"],
                      ["plan=tiny", "light=dim", "light.intensity=0.9", "search.trial=2"]):
            hydras = OmegaConf.to_container(loader.load_sweep_config(master, trial))
            assert OmegaConf.to_container(launch.take(trial)) == hydras  # launched as it comes
            launch.compose(trial)  # checked first (search/loop.py rejects), Hydra's node not yet a job's
            assert OmegaConf.to_container(launch.take(trial)) == hydras
        assert len(launch.compositions.cache) == 2  # light=dim twice: one composition


def test_a_compositions_copy_is_deepcopys_node_for_node():
    """Each point's config is a copy of its cached composition (search/compose.py copied), made directly rather
    than by copy.deepcopy: the same nodes (types, metadata, values, flags), parented in the copy, nothing mutable
    shared with the original; a value set in the copy leaves the original as it was."""
    import copy

    from conftest import hydra_loader
    from hydra.types import RunMode
    from omegaconf import Container, OmegaConf, open_dict

    from garage_exp.search.compose import copied

    with hydra_loader() as loader:
        master = loader.load_configuration("config", ["hydra/sweeper=search", "space=wide"], RunMode.MULTIRUN)
        cfg = loader.load_sweep_config(master, ["space=wide", "plan=generated"])
    def resolved(config):  # the job's part (hydra's holds values the launch sets)
        return {key: OmegaConf.to_container(config[key], resolve=True) if isinstance(config[key], Container)
                else config[key] for key in config if key != "hydra"}

    resolved(cfg)  # fills the flag caches
    assert cfg._metadata.resolver_cache  # ${now:...} of hydra's dirs
    ours, theirs = copied(cfg), copy.deepcopy(cfg)

    def walk(a, b, original, parent_a, parent_b):
        assert type(a) is type(b) and a is not original
        assert set(a.__dict__) == set(b.__dict__)
        assert a._metadata == b._metadata and a._metadata is not original._metadata
        assert a._metadata.flags is not original._metadata.flags
        assert a._metadata.resolver_cache is not original._metadata.resolver_cache
        assert a.__dict__["_parent"] is parent_a and b.__dict__["_parent"] is parent_b
        assert a.__dict__["_flags_cache"] == b.__dict__["_flags_cache"]
        for key in set(a.__dict__) - {"_metadata", "_parent", "_flags_cache", "_content"}:
            assert a.__dict__[key] == b.__dict__[key], key
        if not isinstance(a, Container):
            return 1
        content = a.__dict__["_content"]
        if not isinstance(content, (dict, list)):
            assert content == b.__dict__["_content"]
            return 1
        keys = content.keys() if isinstance(content, dict) else range(len(content))
        assert list(keys) == list(b.__dict__["_content"].keys() if isinstance(content, dict)
                                  else range(len(b.__dict__["_content"])))
        return 1 + sum(walk(content[k], b.__dict__["_content"][k], original.__dict__["_content"][k], a, b)
                       for k in keys)

    assert walk(ours, theirs, cfg, None, None) > 500  # the wide space: ~630 nodes
    assert OmegaConf.to_container(ours) == OmegaConf.to_container(theirs) == OmegaConf.to_container(cfg)
    assert resolved(ours) == resolved(cfg)
    before = OmegaConf.to_container(cfg)
    OmegaConf.update(ours, "light.intensity", 0.123, merge=True)
    OmegaConf.update(ours, "case.actors.target.distance", 7, merge=True)
    with open_dict(ours):
        ours.hydra.overrides.task = ["x=1"]
    assert OmegaConf.to_container(cfg) == before and ours.light.intensity == 0.123
    assert OmegaConf.is_struct(ours) and OmegaConf.get_type(ours) is OmegaConf.get_type(cfg)


def test_a_drawn_number_is_the_override_hydras_parser_makes_of_it():
    """The cached composition makes a `key=number` line's Override itself (search/compose.py number_override);
    on drawn values and on the grammar's edge cases it is Hydra's own, value type included, and any line that
    is not a plain decimal number is left to the grammar."""
    import random

    from hydra.core.override_parser.overrides_parser import OverridesParser

    from garage_exp.search.compose import number_override
    from garage_exp.search.space import format_value

    parser = OverridesParser.create()
    rng = random.Random(0)
    drawn = [f"case.actors.target.hue={format_value(rng.uniform(-400.0, 400.0))}" for _ in range(300)]
    drawn += [f"plan.seed={format_value(rng.randint(-10 ** 6, 10 ** 6))}" for _ in range(100)]
    edges = ["case=1", "a=0", "a=-0", "a=-0.0", "a=0.5", "a=-12.000", "a_b.c_d=3"]
    grammar = ["a=007", "a=00.5", "a=1_000", "a=1.", "a=.5", "a=+3", "a=inf", "a=1e-06", "a=1.5e3", "1a=3",
               "a.1=3", "a/b=1", "+a=1", "~a", "a=abc", "a='1'", "a=[1,2]", "a=null"]
    for line in drawn + edges:
        ours, hydras = number_override(line), parser.parse_overrides([line])[0]
        assert ours == hydras and repr(ours.value()) == repr(hydras.value()), line
    assert all(number_override(line) is None for line in grammar)


def test_the_launch_of_a_draw_just_checked_takes_the_checks_composition_once():
    """A space with requirements composes each draw to check it (search/loop.py rejects); its launch takes that
    composition, not another copy (0.05 s a scenario), and only for the same overrides and once: a second launch,
    or a launch of other overrides, composes its own, which still equals Hydra's."""
    from types import SimpleNamespace

    from conftest import hydra_loader
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from garage_exp.search.launch import CachedLaunch

    with hydra_loader() as loader:
        master = loader.load_configuration("config", ["hydra/sweeper=search", "plan=tiny"], RunMode.MULTIRUN)
        launch = CachedLaunch(SimpleNamespace(config_loader=loader), None, master, set(levels()))
        draw = ["plan=tiny", "light.intensity=0.3", "search.trial=0"]
        checked = launch.compose(draw)
        assert list(checked.hydra.overrides.task) != draw  # the check reads none of Hydra's node
        assert launch.take(list(draw)) is checked
        assert list(checked.hydra.overrides.task) == draw  # the launch made it a job's (equal to Hydra's: above)
        again = launch.take(draw)
        assert again is not checked and launch.last is None  # taken once: the next launch composes its own
        other = ["plan=tiny", "light.intensity=0.9", "search.trial=1"]
        launch.compose(draw)
        took = launch.take(other)
        hydras = loader.load_sweep_config(master, other)
        assert OmegaConf.to_container(took) == OmegaConf.to_container(hydras)
        # a copy of the cached composition keeps Hydra's node types and flags, not only its values
        for key in hydras:
            assert OmegaConf.get_type(took, key) == OmegaConf.get_type(hydras, key), key
        assert OmegaConf.is_struct(took) and OmegaConf.is_struct(took.camera) == OmegaConf.is_struct(hydras.camera)


def test_a_suite_scenario_of_a_late_search_says_lateness():
    """A scenario file's header names the objective's value (issue 31, item 5): lateness, not difficulty."""
    from optuna.trial import create_trial

    from garage_exp.search.suite import scenario_yaml

    job = compose_cfg("case=stepout", "search.objective=late", hydra=True)
    trial = create_trial(values=[0.6], user_attrs={"fair_frames": 3, "visible_fraction": 0.8})
    head = scenario_yaml(job, "hard_1", trial).splitlines()[1]
    assert "lateness 0.600 over 3 fair frame(s)" in head and "difficulty" not in head


def test_a_study_is_continued_only_under_the_objective_it_was_made_for(tmp_path):
    """late and difficulty both have one maximised value: the names stored in the study tell them apart, so a
    difficulty search never adds its values to a study of lateness."""
    storage = f"search.storage=sqlite:///{tmp_path / 'optuna.db'}"
    late = compose_cfg("search.objective=late", storage).search
    study = study_mod.open_study(late, "mine", 0)
    assert study.user_attrs["direction_names"] == ["lateness"] and study.metric_names == ["lateness"]
    # the objectives' own trial attributes, as they declare them, for the report (report/trials.attr_headings)
    assert study.user_attrs["attr_headings"] == {"late": "late", "detection_distance": "detection distance (m)",
                                                 "ttc_at_detection": "TTC at detection (s)"}
    with pytest.raises(GarageError, match=r"made for another objective \(lateness, not difficulty\)"):
        study_mod.open_study(compose_cfg(storage).search, "mine", 0)


def test_a_frame_budget_stops_the_study_once_its_trials_rendered_that_many(tmp_path):
    """search.frames: trials are asked until their jobs' frames reach the budget (the one that crosses it ends),
    `trials` staying the cap; a resumed study spent already counts."""
    from garage_exp.search.loop import rendered_frames

    def launch(batch, idx):  # each job renders 3 frames (and none crashes, whatever the draws)
        return [Ret({**fake_job([*job, "light.intensity=0.5"]), "frames": 3.0}) for job in batch]

    study = run_loop(tmp_path, 20, launch=launch, frames=7)
    assert len(study.trials) == 3 and rendered_frames(study) == 9  # 3 + 3 < 7 <= 3 + 3 + 3
    again = run_loop(tmp_path, 20, launch=launch, frames=7)
    assert len(again.trials) == 3  # spent: nothing more
    assert len(run_loop(tmp_path, 4, launch=launch, frames=100).trials) == 4  # the cap


def test_a_negative_frame_budget_is_refused(tmp_path):
    with pytest.raises(GarageError, match="search.frames"):
        study_mod.check_search(search_node(tmp_path, frames=-1).search)


def test_the_check_of_a_space_composes_once_per_combination_of_group_levels(monkeypatch):
    """The search's check probes every choice and each interval's ends (the wide space: about 300 points); each
    point is composed as the launcher composes a trial (search/compose.py), so Hydra composes once per combination
    of group levels, not once per point (each 0.3-0.9 s: most of the check's minutes on the wide space)."""
    from conftest import hydra_loader
    from hydra.types import RunMode
    from omegaconf import open_dict

    from garage_exp.core.state import STATE
    from garage_exp.search import sweep

    with hydra_loader() as loader:
        task = ["hydra/sweeper=search", "plan=small", "case=light", "light=choice(bright,dim)",
                "light.intensity=interval(0.3,0.9)", "case.actors.target.distance=interval(4.0,8.0)",
                "case.actors.target.yaw=interval(-20.0,20.0)", "detector.models=[yolo11n_int8_openvino_model]"]
        master = loader.load_configuration("config", task, RunMode.MULTIRUN)
        with open_dict(master):
            master.hydra.overrides.task = task
        composed = []
        real = type(loader).load_sweep_config
        monkeypatch.setattr(type(loader), "load_sweep_config",
                            lambda self, cfg, overrides: composed.append(list(overrides)) or real(self, cfg, overrides))
        monkeypatch.setattr(sweep, "load_models", lambda job: None, raising=False)
        import garage_exp.run.preflight as preflight_mod

        monkeypatch.setattr(preflight_mod, "load_models", lambda job: None)
        STATE.begin()
        space = sweep.check(master, loader)
    probed = 2 * 3 + 2 + 1  # three intervals' ends and middle, the choice's levels, the space's middle
    assert len(space.params) == 4 and len(composed) < probed
    # the fixed part, then one composition per level of `light` (the intervals' probes share them)
    assert sorted(tuple(o for o in c if o.startswith("light=")) for c in composed[1:]) == [("light=bright",),
                                                                                          ("light=dim",)]
