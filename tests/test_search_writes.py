"""A trial's parameters and attributes written in one transaction (garage_exp/search/writes.py): the database
holds what Optuna's own writes leave, written when the block ends, and Optuna's checks still refuse a
contradicting distribution."""

from __future__ import annotations

import contextlib
from types import SimpleNamespace

import optuna
import pytest
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

from garage_exp.search import study as study_mod
from garage_exp.search import writes

SPACE = {"x": FloatDistribution(0.0, 1.0), "n": IntDistribution(1, 9), "kind": CategoricalDistribution(["a", "b"]),
         "log": FloatDistribution(0.1, 10.0, log=True)}


def study(tmp_path, name: str) -> optuna.Study:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna.create_study(study_name=name, storage=f"sqlite:///{tmp_path / name}.db",
                               sampler=optuna.samplers.RandomSampler(seed=3))


def stored(tmp_path, name: str) -> list[tuple]:
    """What the database holds, read by a fresh storage (nothing cached)."""
    trials = optuna.load_study(study_name=name, storage=f"sqlite:///{tmp_path / name}.db").trials
    return [(t.number, t.state, t.params, t.distributions, t.user_attrs) for t in trials]


def test_the_parameters_of_an_ask_are_written_as_optunas_own_writes_leave_them_when_the_block_ends(tmp_path):
    plain, held = study(tmp_path, "plain"), study(tmp_path, "held")
    for _ in range(4):
        plain.ask(SPACE)
    for _ in range(4):
        with writes.params_at_once(held):
            trial = held.ask(SPACE)
            assert trial.params and stored(tmp_path, "held")[-1][2] == {}  # drawn, not yet in the database
        assert stored(tmp_path, "held")[-1][2] == trial.params
    assert stored(tmp_path, "plain") == stored(tmp_path, "held")
    assert "_set_trial_param" not in vars(writes.backend(held))  # the storage's own method again


def test_a_distribution_that_contradicts_the_studys_is_refused_as_optuna_refuses_it(tmp_path):
    held = study(tmp_path, "held")
    held.ask(SPACE)
    with pytest.raises(ValueError, match="Cannot set different distribution kind"):
        with writes.params_at_once(held):
            held.ask({"x": CategoricalDistribution(["a", "b"])})
    fresh = study(tmp_path, "fresh")  # the study's first trial: no distribution cached, read from the database
    fresh.ask(SPACE)
    other = optuna.load_study(study_name="fresh", storage=f"sqlite:///{tmp_path / 'fresh'}.db")
    with pytest.raises(ValueError, match="Cannot set different distribution kind"):
        with writes.params_at_once(other):
            other.ask({"n": FloatDistribution(0.0, 1.0)})


def test_a_block_that_raises_writes_nothing_and_gives_the_storage_its_method_back(tmp_path):
    held = study(tmp_path, "held")
    with pytest.raises(KeyboardInterrupt):
        with writes.params_at_once(held):
            held.ask(SPACE)
            raise KeyboardInterrupt
    assert stored(tmp_path, "held")[0][2] == {}
    assert "_set_trial_param" not in vars(writes.backend(held))


def test_attributes_set_together_are_written_together_the_last_value_of_a_key_kept(tmp_path):
    plain, held = study(tmp_path, "plain"), study(tmp_path, "held")
    for s in (plain, held):
        trial = s.ask(SPACE)
        with writes.attrs_at_once(s) if s is held else contextlib.nullcontext():
            trial.set_user_attr("overrides", ["a=1", "b=2"])
            trial.set_user_attr("worker", "w1")
            trial.set_user_attr("worker", "w2")
            trial.set_user_attr("estimate", {"visible": 0.5})
            assert trial.user_attrs["worker"] == "w2"  # the trial's own copy has them at once
        s.tell(trial, 1.0)
    assert stored(tmp_path, "plain") == stored(tmp_path, "held")
    assert stored(tmp_path, "held")[0][4] == {"overrides": ["a=1", "b=2"], "worker": "w2",
                                             "estimate": {"visible": 0.5}}


def test_a_study_in_memory_is_written_as_ever():
    s = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=3))
    with writes.params_at_once(s), writes.attrs_at_once(s):
        trial = s.ask(SPACE)
        trial.set_user_attr("k", 1)
    assert s.trials[0].params == trial.params and s.trials[0].user_attrs == {"k": 1}


def test_a_key_written_again_is_replaced_and_a_finished_trial_refuses_attributes_as_optuna_refuses(tmp_path):
    """write_attrs's one upsert statement for all keys: a key set in an earlier block gets its new value, the
    others stay, and a trial already told is refused (Optuna's check), whichever writes them."""
    plain, held = study(tmp_path, "plain"), study(tmp_path, "held")
    for s in (plain, held):
        trial = s.ask(SPACE)
        with writes.attrs_at_once(s) if s is held else contextlib.nullcontext():
            trial.set_user_attr("overrides", ["a=1"])
            trial.set_user_attr("worker", "w1")
        with writes.attrs_at_once(s) if s is held else contextlib.nullcontext():
            trial.set_user_attr("worker", "w2")
            trial.set_user_attr("rejected", "visible 0.1 < 0.3")
        s.tell(trial, state=optuna.trial.TrialState.PRUNED)
        with pytest.raises(RuntimeError, match="has already finished"):
            with writes.attrs_at_once(s) if s is held else contextlib.nullcontext():
                trial.set_user_attr("late", 1)
    assert stored(tmp_path, "plain") == stored(tmp_path, "held")
    assert stored(tmp_path, "held")[0][4] == {"overrides": ["a=1"], "worker": "w2", "rejected": "visible 0.1 < 0.3"}


@pytest.fixture
def reads(monkeypatch) -> list[int]:
    """The trial ids the database storage reads back (RDBStorage.get_trial), in order."""
    from optuna.storages import RDBStorage

    seen: list[int] = []
    real = RDBStorage.get_trial
    monkeypatch.setattr(RDBStorage, "get_trial", lambda self, trial_id: seen.append(trial_id) or real(self, trial_id))
    return seen


def lean(s: optuna.Study) -> optuna.Study:
    """The study as a random search's loop holds it (search/study.lean): its database storage, no cache."""
    return study_mod.lean(s, SimpleNamespace(sampler="random", mode="search"))


def test_a_trial_told_from_its_own_copy_is_stored_as_optunas_tell_stores_it_without_reading_it_back(tmp_path,
                                                                                                      reads):
    """told_from_its_copy: the database ends as Optuna's own tell leaves it (complete and pruned, with
    attributes and a reported value), the trial is not read back for its tell, and a trial another worker
    finished meanwhile is still refused."""
    plain, held = study(tmp_path, "plain"), study(tmp_path, "held")
    for s in (plain, held):
        direct = lean(s)
        for k, state in enumerate([optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED]):
            trial = direct.ask(SPACE)
            trial.set_user_attr("overrides", [f"x={k}"])
            trial.report(0.25, step=3)
            reads.clear()
            with writes.told_from_its_copy(direct, trial) if s is held else contextlib.nullcontext():
                direct.tell(trial, 0.5 if state == optuna.trial.TrialState.COMPLETE else None, state=state)
            assert (reads == []) == (s is held)
        assert "get_trial" not in vars(writes.backend(s))  # the class's own again
    assert stored(tmp_path, "plain") == stored(tmp_path, "held")
    assert [t[1] for t in stored(tmp_path, "held")] == [optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED]
    direct = lean(held)
    trial = direct.ask(SPACE)
    optuna.load_study(study_name="held", storage=f"sqlite:///{tmp_path / 'held'}.db").tell(
        trial.number, state=optuna.trial.TrialState.FAIL)  # another worker fails it (a stale heartbeat)
    with pytest.raises(RuntimeError, match="has already finished"):
        with writes.told_from_its_copy(direct, trial):
            direct.tell(trial, 0.5)


def test_an_ask_without_reading_its_trial_back_holds_the_trial_the_database_holds(tmp_path, reads):
    """asked_without_reading: the new trial's copy is the one its write handed back, equal to what a fresh read of
    the database gives (number, state, start, no parameters yet); the ask reads nothing back; the asks, their
    parameters and tells leave the database as Optuna's own; an enqueued trial is read back as ever."""
    plain, held = study(tmp_path, "plain"), study(tmp_path, "held")
    for s in (plain, held):
        direct = lean(s)
        for k in range(3):
            reads.clear()
            with writes.params_at_once(direct), writes.asked_without_reading(direct) if s is held \
                    else contextlib.nullcontext():
                trial = direct.ask()
                fresh = optuna.storages.RDBStorage.get_trial(writes.backend(s), trial._trial_id)
                reads.remove(trial._trial_id)  # the test's own read
                assert trial._cached_frozen_trial == fresh  # as the database holds it, before any draw
                trial.suggest_float("x", 0.0, 1.0)
            assert (reads == []) == (s is held)
            direct.tell(trial, float(k))
        direct.enqueue_trial({"x": 0.25})
        reads.clear()
        with writes.asked_without_reading(direct) if s is held else contextlib.nullcontext():
            trial = direct.ask()
            assert trial.suggest_float("x", 0.0, 1.0) == 0.25
        assert reads  # the enqueued trial read back (it was made before, from a template)
        direct.tell(trial, 9.0)
        assert not {"create_new_trial", "get_trial"} & set(vars(writes.backend(s)))  # the class's own again
    assert stored(tmp_path, "plain") == stored(tmp_path, "held")
