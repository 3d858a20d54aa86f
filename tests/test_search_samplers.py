"""A seeded search draws the same trials however it is run: in one go, resumed, or by several workers on one
storage (search/study.py: NumberedRandom, NumberedTPE). Optuna's own samplers start their seeded stream again in
every process, so a resumed random search redrew its first trials and a second worker drew the first worker's."""

from __future__ import annotations

import optuna
import pytest
from omegaconf import OmegaConf

from garage_exp.search import study as study_mod
from garage_exp.search.schema import SearchConf

SPACE = {"x": optuna.distributions.FloatDistribution(0.0, 1.0),
         "light": optuna.distributions.CategoricalDistribution(["bright", "clear", "moderate", "dim"])}


def conf(name: str):
    search = OmegaConf.structured(SearchConf)
    search.sampler, search.startup = name, 4
    return search


def draws(storage: str, name: str, counts: list[int], study_name: str) -> list[tuple]:
    """`counts[k]` asks by the k-th process (a new sampler opening the same study), each trial told at once."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out = []
    for count in counts:
        study = optuna.create_study(storage=storage, study_name=study_name, load_if_exists=True,
                                    sampler=study_mod.sampler(conf(name), 7, SPACE))
        for _ in range(count):
            trial = study.ask(SPACE)
            out.append((round(trial.params["x"], 9), trial.params["light"]))
            study.tell(trial, trial.params["x"])
    return out


@pytest.mark.parametrize("name", ["random", "tpe"])
def test_a_resumed_search_draws_what_one_uninterrupted_search_draws(tmp_path, name):
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    whole = draws(storage, name, [8], "whole")
    resumed = draws(storage, name, [3, 5], "resumed")
    assert resumed == whole
    assert len(set(whole)) == len(whole)  # no trial drawn twice


@pytest.mark.parametrize("name", ["random", "tpe"])
def test_two_workers_on_one_study_draw_different_trials(tmp_path, name):
    """Two samplers opened on one storage asking in turn (two workers): no scenario drawn twice."""
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    workers = [optuna.create_study(storage=storage, study_name="shared", load_if_exists=True,
                                   sampler=study_mod.sampler(conf(name), 7, SPACE)) for _ in range(2)]
    seen = []
    for k in range(8):
        study = workers[k % 2]
        trial = study.ask(SPACE)
        seen.append(trial.params["x"])
        study.tell(trial, trial.params["x"])
    assert len(set(seen)) == len(seen)


def test_another_seed_draws_other_trials(tmp_path):
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    seven = draws(storage, "random", [4], "a")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(storage=storage, study_name="b", sampler=study_mod.sampler(conf("random"), 8, SPACE))
    assert [round(study.ask(SPACE).params["x"], 9) for _ in range(4)] != [x for x, _ in seven]
