"""The loop on the wide space (issue 50, items 1, 2 and 4) on small settings: the held-out sample is a seeded
Sobol' sequence over the whole space on generated garages no training search draws (a disjoint seed range, and
a layout family of its own), its draws are the same for the same seed, the arms' budgets are equal there too,
the failure rate counts neither rejected nor infeasible draws and is split into the sample's parts, and the
estimate carries the power of the held-out sample. The steps themselves are faked (test_loop_rounds.py's
`fake_steps`): what is checked is what the loop asks its commands for."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest
from conftest import compose_cfg, run_in_process
from test_loop_rounds import fake_steps, small

TRAIN, HELD = (0, 499_999), (500_000, 999_999)


def wide(*args: str):
    """The loop's config on space=wide, as `python -m garage_exp.loop space=wide ARGS` composes it."""
    from garage_exp.loop.schema import space_by_name

    return small(space_by_name(["space=wide", *args]))


def shipped(name: str):
    """A shipped loop config (conf/NAME.yaml) as `python -m garage_exp.loop --config-name NAME` composes it."""
    from garage_exp.core import shell
    from garage_exp.loop.app import COMMAND

    return shell.compose(name, [], schemas=COMMAND.schemas)


def arg(cmd: list[str], key: str) -> str | None:
    return next((a.split("=", 1)[1] for a in cmd if a.startswith(key + "=")), None)


def test_the_held_out_sample_is_the_same_for_the_same_seed_and_on_held_out_garages():
    from garage_exp.loop import garages, heldout, steps

    cfg = wide()
    space = steps.with_garage(cfg, garages.heldout(cfg))
    assert heldout.requires(cfg)  # the wide space rejects draws: the sequence's next points are enqueued after
    a = heldout.draws(space, 8, 0, rejecting=True)
    assert len(a) == 8 * (1 + heldout.SPARE) and a == heldout.draws(space, 8, 0, rejecting=True)
    assert a != heldout.draws(space, 8, 1, rejecting=True)
    assert a[:8] == heldout.sample(space, 8, 0)  # the sample is the sequence's start; the spare points follow
    params = heldout.space_params(space)
    whole = heldout.space_params(["space=wide"])  # every factor of the space, and the family drawn too
    assert set(params) == {*whole, "plan.generator.family"}
    assert all(HELD[0] <= p["plan.seed"] <= HELD[1] for p in a)
    assert {p["plan.generator.family"] for p in a[:8]} == {"loop", "comb", "grid", "spine"}  # Sobol': balanced


def test_no_training_search_draws_a_held_out_garage(tmp_path, monkeypatch):
    """Every search of a loop on space=wide, as the loop runs it: the base data and every generator on generated
    garages of the training seeds and the space's families; the held-out sample on the held-out seeds, with the
    held-out family among its choices. No training plan, seed or family is the held-out sample's."""
    from garage_exp.loop.app import run_loop
    from garage_exp.search.space import distribution, parse

    ran = fake_steps(monkeypatch, tmp_path)
    out = run_loop(wide(f"dir={tmp_path / 'loop'}", "tracking.uri=sqlite:///x.db", "rounds=2", "seeds=[0]",
                        "trials=6", "frames=0", "train_frames=8", "base_trials=4", "heldout_trials=3", "photos=false",
                        "arms.Q.sampler=tpe", "fixed=[]"))
    searches = {arg(c, "search.study"): c for c in ran if "hydra/sweeper=search" in c}
    assert sorted(searches) == ["base", "gen_Q_r1_s0", "gen_Q_r2_s0", "gen_R_r1_s0", "gen_R_r2_s0",
                                "gen_T_r1_s0", "gen_T_r2_s0", "heldout"]

    def seeds(cmd):
        (o,) = parse([f"plan.seed={arg(cmd, 'plan.seed')}"])
        d = distribution(o)
        return d.low, d.high

    for name, cmd in searches.items():
        assert arg(cmd, "plan") == "generated" and "space=wide" in cmd  # never a shipped training plan
        if name == "heldout":
            assert seeds(cmd) == HELD and arg(cmd, "plan.generator.family") == "choice(loop,comb,grid,spine)"
        else:  # the space's own families ([loop,comb,grid]: its entry, not overridden) on the training seeds
            assert seeds(cmd) == TRAIN and arg(cmd, "plan.generator.family") is None
    book = pd.DataFrame(out["book"])  # equal budgets per arm, as on the shipped plans
    assert book.train_frames.tolist() == [8] * 6 and book.epochs.nunique() == 1


@pytest.mark.parametrize("bad, expect", [
    ("garages.heldout_seeds=[400000,999999]", "garages.heldout_seeds: the held-out seeds [400000, 999999] overlap "
                                              "the training seeds [0, 499999]: held-out garages must be ones no "
                                              "training frame came from"),
    ("garages.heldout_families=[comb]", "garages.heldout_families: ['comb']: a held-out family is also a training "
                                        "family")])
def test_held_out_garages_that_training_shares_are_refused_in_one_line(tmp_path, bad, expect):
    from garage_exp.loop.app import cli

    r = run_in_process(["space=wide", bad, f"dir={tmp_path / 'loop'}", "estimate=true"], tmp_path, entry=cli)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [f"garage_exp.loop: {expect}"], r.stderr
    assert not (tmp_path / "loop").exists()


def test_the_failure_rate_counts_scenarios_not_rejected_or_infeasible_draws():
    from garage_exp.loop import heldout
    from garage_exp.loop.steps import Trial

    fam = "plan.generator.family"
    held = [Trial("heldout", k, "COMPLETE", None, None, 1, {fam: f}) for k, f in enumerate(
        ["loop", "spine", "grid", "spine"])]
    held += [Trial("heldout", 4, "PRUNED", None, None, 0, {fam: "loop"}, rejected=True),
             Trial("heldout", 5, "PRUNED", None, None, 0, {fam: "comb"}, infeasible=True)]
    frames = pd.DataFrame({"trial": [0, 1, 2, 3], "fair": [True] * 4, "confidence": [0.1, 0.2, 0.9, 0.9]})
    got = heldout.failures(frames, held, hard_below=0.4)
    assert (got["failures"], got["scenarios"], got["failed"]) == (2, 4, [0, 1])
    parts = heldout.parts(held, ["spine"])
    assert [t.number for t in parts["new_family"]] == [1, 3]
    assert heldout.failures(frames, parts["new_family"], 0.4)["per_100"] == 50.0
    assert heldout.acceptance(held, enqueued=5) == {"draws": 6, "accepted": 5, "acceptance": 5 / 6,
                                                    "infeasible": 1, "scenarios": 4, "past_sobol": 1}
    assert heldout.parts([Trial("heldout", 0, "COMPLETE", None, None, 1, {"light": "dim"})], ["spine"]) == {}


def test_the_power_estimate_on_known_numbers():
    """scenarios_for against the formula for two independent samples: n = 2 ((z_(1 - alpha / 2m) + z_power) / h)^2,
    h Cohen's (the variance of 2 asin(sqrt(p)) is 1/n per sample)."""
    from scipy.stats import norm

    from garage_exp.loop import cost
    from garage_exp.loop.stats import scenarios_for

    for rate, m in ((0.3, 1), (0.4, 12)):
        h = 2 * math.asin(math.sqrt(rate)) - 2 * math.asin(math.sqrt(0.8 * rate))
        n = 2 * ((norm.ppf(1 - 0.05 / (2 * m)) + norm.ppf(0.8)) / h) ** 2
        assert scenarios_for(rate, 0.2, m) == math.ceil(n)
    from garage_exp.loop import report

    d0 = pd.DataFrame([{"arm": "D0", "round": 0, "seed": -1, "suite": "heldout", "per_100": 40.0}])
    assert report.power(d0, ["R"], 1, comparisons=12)["scenarios_needed_20pct_holm"] == scenarios_for(0.4, 0.2, 12)
    cfg = compose_cfg(config="loop")
    assert cost.comparisons(cfg) == 3 + 3 * 3  # the report's Holm family: 3 pairs, each arm against D0 three ways
    assert "held-out scenarios per detector detect 20 % fewer failures" in cost.power_line(cfg)


def test_the_cost_model_counts_rejected_draws():
    from garage_exp.loop import cost

    cfg = small(["rounds=1", "seeds=[0]", "base_trials=4", "heldout_trials=2", "trials=3", "frames=0",
                 "cost.search_s=20", "cost.render_s_per_frame=1", "cost.trial_overhead_s=2",
                 "cost.frames_per_trial=1", "cost.acceptance=0.5", "cost.reject_s=4"])
    assert cost.estimate(cfg)["base data"] == pytest.approx(20 + 4 * (2 + 1 + 4))  # one rejected draw a trial


def test_the_shipped_wide_loop_fits_its_budget_and_its_power():
    """conf/loop_wide.yaml at its measured rates: within 2.5 hours on the 2-core CPU, on space=wide."""
    from garage_exp.loop import cost, garages

    cfg = shipped("loop_wide")
    assert garages.generated(cfg) and cost.estimate(cfg)["total"] <= 2.5 * 3600
    assert cfg.heldout_trials >= 1024
    gpu = shipped("loop_gpu")
    assert garages.generated(gpu) and gpu.heldout_trials > cfg.heldout_trials and len(gpu.seeds) > len(cfg.seeds)
    assert "enough" in cost.power_line(gpu)


def test_the_cells_say_how_many_the_sample_reaches(tmp_path):
    from omegaconf import OmegaConf

    from garage_exp.loop import cells
    from garage_exp.search.archive import Grid
    from garage_exp.search.schema import wide_descriptors

    grid = Grid(OmegaConf.structured(wide_descriptors()))
    assert cells.reach({0: (0, 0, 0, 0, 0, 0), 1: (0, 0, 0, 0, 0, 0), 2: (1, 0, 0, 0, 0, 1)}, grid) == {
        "reached": 2, "cells": 864}
    scores = pd.DataFrame([{"arm": "D0", "round": 0, "suite": "heldout", "failed": [0]}])
    table = cells.cell_table(scores, {0: (0, 0, 0, 0, 0, 0), 1: (0, 0, 0, 0, 0, 0)}, grid)
    row = table.iloc[0]
    assert (row.failures, row.scenarios) == (1, 2) and row.low < 0.5 < row.high  # Wilson, seeds pooled
    marginals = cells.marginal_table(table, grid, 1)  # per descriptor bin, the cells pooled
    first = marginals[(marginals.descriptor == "target_class")].set_index("bin")
    assert first.loc["small_person", "tests"] == 2 and first.loc["small_person", "failed_share"] == 0.5
    assert first.loc["car", "tests"] == 0 and len(marginals) == 4 + 4 + 3 + 3 + 3 + 2
    assert cells.draw_marginals(marginals, tmp_path / "m.png").stat().st_size > 0


def test_a_base_data_too_small_for_the_replay_stops_before_the_fine_tuning(tmp_path):
    """One-shot draws are often infeasible: base_trials scenarios may hold fewer frames than a fine-tuning replays
    (train_frames x replay_fraction); the loop says so in one line (exit 1) instead of the training's refusal."""
    from garage_exp.core.errors import JobFault
    from garage_exp.loop import budget

    pool = []
    for k in range(3):
        (tmp_path / str(k) / "images").mkdir(parents=True)
        (tmp_path / str(k) / "images" / "0000_front.png").write_bytes(b"")
        pool.append(tmp_path / str(k))
    cfg = small(["train_frames=6", "replay_fraction=0.5"])
    budget.check_replay(cfg, pool, "its dir")  # 3 frames replayed, 3 held
    cfg.replay_fraction = 1.0
    with pytest.raises(JobFault, match="the base data holds 3 replay frames outside its validation scenarios, "
                                       "fewer than the 6 a fine-tuning replays"):
        budget.check_replay(cfg, pool, "its dir")


def test_a_held_out_trial_may_have_its_own_measured_rate():
    from garage_exp.loop import cost

    rates = ["cost.search_s=20", "cost.render_s_per_frame=1", "cost.trial_overhead_s=2", "cost.frames_per_trial=1"]
    cfg = small(["rounds=1", "seeds=[0]", "base_trials=4", "heldout_trials=10", "trials=3", "frames=0", *rates])
    assert cost.estimate(cfg)["held-out sample"] == pytest.approx(20 + 10 * 3)  # a search's trial
    cfg = small(["rounds=1", "seeds=[0]", "base_trials=4", "heldout_trials=10", "trials=3", "frames=0", *rates,
                 "cost.heldout_trial_s=5"])
    assert cost.estimate(cfg)["held-out sample"] == pytest.approx(20 + 10 * 5)
    assert cost.estimate(cfg)["base data"] == pytest.approx(20 + 4 * 3)  # the searches keep theirs


def test_a_replay_pool_of_people_joins_every_fine_tunings_replay_and_never_its_validation(tmp_path, monkeypatch):
    """`replay_pool`: a QMC study on the training garages, its params winning over the space's (here: people as
    every target), at a seed of its own; its scenarios join the replay of every fine-tuning and count towards what
    the replay needs, the validation split stays the base data's; the cost model counts its trials."""
    from garage_exp.loop import cost, replay
    from garage_exp.loop.app import run_loop

    people = "case.actors.target.type=choice(child,adult,crouching)"
    ran = fake_steps(monkeypatch, tmp_path)
    args = [f"dir={tmp_path / 'loop'}", "tracking.uri=sqlite:///x.db", "rounds=1", "seeds=[0]", "trials=4",
            "frames=0", "train_frames=8", "base_trials=4", "heldout_trials=3", "photos=false", "arms.Q.sampler=tpe",
            "fixed=[]", "replay_fraction=4.0", f'++replay_pool={{people: {{trials: 5, params: ["{people}"]}}}}']
    # 32 replay frames asked: the base data's 3 training scenarios hold 12, the pool's 5 another 20
    run_loop(wide(*args))
    searches = {arg(c, "search.study"): c for c in ran if "hydra/sweeper=search" in c}
    pool = searches["replay_people"]
    assert arg(pool, "case.actors.target.type") == "choice(child,adult,crouching)"  # the pool's, not the space's
    assert pool.index(people) < pool.index("space=wide")  # given before the space: the command's own key wins
    assert arg(pool, "search.sampler") == "qmc" and arg(pool, "search.seed") == str(replay.seed("people")) != "0"
    assert arg(pool, "plan") == "generated" and arg(pool, "search.trials") == "5"
    assert arg(pool, "plan.seed") == arg(searches["base"], "plan.seed") == f"int(interval({TRAIN[0]},{TRAIN[1]}))"
    for cmd in (c for c in ran if "garage_exp.train" in c):
        lists = arg(cmd, "replay").strip("[]").split(",")
        assert [Path(p).name for p in lists] == ["base_train.yaml", "replay_people.yaml"]
        assert Path(arg(cmd, "val").strip("[]")).name == "base_val.yaml"
    import yaml

    listed = yaml.safe_load((tmp_path / "loop" / "data" / "replay_people.yaml").read_text())["train"]
    assert len(listed) == 5 and all("/replay_people/" in p for p in listed)
    cfg = wide(*args)
    assert cost.estimate(cfg)["replay pools"] == pytest.approx(cost.estimate(cfg)["base data"] / 4 * 5
                                                                - cfg.cost.search_s / 4)


def test_a_replay_pool_too_small_is_refused_before_the_fine_tuning(tmp_path, monkeypatch):
    from garage_exp.core.errors import JobFault
    from garage_exp.loop.app import run_loop

    fake_steps(monkeypatch, tmp_path)
    with pytest.raises(JobFault, match="the base data and its replay pools hold 16 replay frames"):
        run_loop(wide(f"dir={tmp_path / 'loop'}", "tracking.uri=sqlite:///x.db", "rounds=1", "seeds=[0]", "trials=4",
                      "frames=0", "train_frames=8", "base_trials=4", "heldout_trials=3", "photos=false",
                      "arms.Q.sampler=tpe", "fixed=[]", "replay_fraction=4.0", "++replay_pool={few: {trials: 1}}"))
