"""The loop in rounds (issue 39, items 2-7) on small settings: the held-out sample's determinism, the failure rate
on it, equal budgets refused in one line, the rounds' bookkeeping and resume (a round done is not rerun), the
statistics (Wilson, Holm, paired by seed, power) on known numbers, the cost model, and the BatchNorm calibration
of the folded COCO detector."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import pandas as pd
import pytest
from conftest import compose_cfg, run_in_process

SPACE = ["case=choice('1','2','3',pedestrian)", "light=choice(bright,clear,moderate,dim)",
         "seed=int(interval(0,9999))"]
NO_ARCHIVE = ["arms.Q.sampler=tpe"]  # the archive sampler (item 1) is another branch's


def test_the_held_out_sample_is_fixed_by_its_seed():
    """The same seed gives the same scenarios, another seed others; a Sobol' sample of 16 balances every choice
    (each of 4 cases and 4 light presets exactly 4 times: its first 2^4 points stratify each axis)."""
    from garage_exp.loop import heldout

    a = heldout.sample(SPACE, 16, seed=0)
    assert a == heldout.sample(SPACE, 16, seed=0)
    assert a != heldout.sample(SPACE, 16, seed=1)
    assert heldout.sample(SPACE, 5, seed=0) == a[:5]  # a smaller sample is the same sequence's start
    assert pd.Series([p["case"] for p in a]).value_counts().to_dict() == {"1": 4, "2": 4, "3": 4, "pedestrian": 4}
    assert set(pd.Series([p["light"] for p in a]).value_counts()) == {4}
    assert all(isinstance(p["seed"], int) and 0 <= p["seed"] <= 9999 for p in a)
    assert len({p["seed"] for p in a}) == 16
    halton = heldout.sample(SPACE, 7, seed=3, method="halton")
    assert halton == heldout.sample(SPACE, 7, seed=3, method="halton") and halton != a[:7]


def test_the_held_out_sample_is_what_the_study_runs(tmp_path):
    """Enqueued in the held-out study, the points are the trials the search asks for, in order; a resumed study
    (one that holds trials) gets nothing twice."""
    import optuna

    from garage_exp.loop import heldout
    from garage_exp.search import space as space_mod

    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    points = heldout.sample(SPACE, 4, seed=2)
    heldout.enqueue(storage, "heldout", points)
    heldout.enqueue(storage, "heldout", points)  # a resumed study: it holds the points already
    study = optuna.load_study(study_name="heldout", storage=storage)
    waiting = study.get_trials(deepcopy=False)
    assert [t.state for t in waiting] == [optuna.trial.TrialState.WAITING] * 4  # each point once, not twice
    params = heldout.space_params(SPACE)
    assert params == {k: space_mod.distribution(o) for k, o in
                      ((o.key_or_group, o) for o in space_mod.parse(SPACE))}
    asked = []
    for _ in range(4):
        trial = study.ask()
        asked.append({name: trial._suggest(name, dist) for name, dist in params.items()})
        study.tell(trial, 0.5)
    assert asked == points
    assert not study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.WAITING,))  # none left to run again
    # a study that ran its points (and more) gets none again when the loop resumes
    heldout.enqueue(storage, "heldout", points)
    assert len(study.get_trials(deepcopy=False)) == 4


def test_the_failure_rate_counts_hard_fair_scenarios_of_the_whole_sample():
    from garage_exp.loop import heldout
    from garage_exp.loop.steps import Trial

    trials = [Trial("heldout", k, "COMPLETE", None, None) for k in range(4)]
    trials.append(Trial("heldout", 4, "PRUNED", None, None))
    frames = pd.DataFrame({"trial": [0, 0, 1, 1, 2, 3, 3], "fair": [True, True, True, False, True, False, False],
                           "confidence": [0.1, 0.5, 0.9, 0.0, 0.39, 0.0, 0.0]})
    got = heldout.failures(frames, trials, hard_below=0.4)
    # trial 0: mean 0.3 fails; 1: 0.9 (its unfair frame does not count); 2: 0.39 fails; 3 and 4: no fair frame
    assert (got["failures"], got["scenarios"], got["failed"]) == (2, 5, [0, 2])
    assert got["per_100"] == 40.0 and got["low"] == pytest.approx(11.76, abs=0.01)
    assert got["high"] == pytest.approx(76.93, abs=0.01)


def test_statistics_on_known_numbers():
    from garage_exp.loop import stats

    assert stats.wilson(0, 30) == pytest.approx((0.0, 0.11351), abs=1e-5)
    assert stats.wilson(15, 30) == pytest.approx((0.33154, 0.66846), abs=1e-5)
    assert all(math.isnan(v) for v in stats.wilson(3, 0))  # no scenarios: no interval
    reject, adjusted = stats.holm([0.01, 0.04, 0.03, float("nan")])
    assert adjusted[:3] == pytest.approx([0.03, 0.06, 0.06]) and adjusted[3] != adjusted[3]
    assert reject == [True, False, False, False]  # uncorrected, 0.04 and 0.03 would pass at 0.05
    got = stats.paired({0: 10.0, 1: 12.0, 2: 14.0, 3: 9.0}, {0: 8.0, 1: 8.0, 2: 9.0, 3: 9.0, 9: 1.0})
    assert got["diff"] == pytest.approx(2.75) and got["seeds"] == 4
    # differences 2, 4, 5, 0 (seed 9 has no pair): sd 2.2174, t(3) 3.1824
    assert (got["low"], got["high"]) == pytest.approx((-0.7783, 6.2783), abs=1e-4)
    assert got["p"] == pytest.approx(0.08924, abs=1e-5)
    assert stats.paired({0: 0.5, 1: 0.7}, 0.6)["diff"] == pytest.approx(0.0)
    # the same difference at every seed: no spread, no test (not p = 1 for none, nor p = 0 for any)
    assert all(math.isnan(stats.paired({0: 0.5, 1: 0.5}, b)["p"]) for b in (0.5, 0.25))
    assert stats.seeds_needed(5.0, 5.0) == pytest.approx(9.94, abs=0.01)  # effect size 1: ten pairs
    assert stats.seeds_needed(0.3, 5.0) == 2.0  # two seeds that nearly agree: past statsmodels' root finder
    assert stats.scenarios_needed(0.30, 0.25) == pytest.approx(1250.1, abs=1.0)
    table = stats.compare([{"a": "Q", "b": "R", "p": 0.01}, {"a": "T", "b": "R", "p": 0.04}])
    assert table.p_holm.tolist() == pytest.approx([0.02, 0.04]) and table.reject_holm.tolist() == [True, True]


def test_unequal_budgets_are_refused_in_one_line(tmp_path):
    """An arm given more of anything the others spend is refused before anything runs; arms repeating the shared
    budget pass."""
    from garage_exp.core.errors import GarageError
    from garage_exp.loop.app import check_budgets, cli

    shipped = compose_cfg(config="loop")
    check_budgets(compose_cfg(f"arms.T.epochs={shipped.epochs}", f"arms.Q.trials={shipped.trials}", config="loop"))
    for override, key in (("arms.Q.trials=99", "trials"), ("arms.T.train_frames=96", "train_frames"),
                          ("arms.Q.epochs=5", "epochs"), ("arms.R.imgsz=640", "imgsz"),
                          ("arms.T.replay_fraction=2.0", "replay_fraction")):
        with pytest.raises(GarageError, match=f"unequal budgets: arm .* has {key}="):
            check_budgets(compose_cfg(override, config="loop"))
    r = run_in_process([f"dir={tmp_path}/loop", "epochs=2", "arms.Q.epochs=5", *NO_ARCHIVE], tmp_path, entry=cli)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "garage_exp.loop: arms.Q.epochs: unequal budgets: arm Q has epochs=5, arm R 2 (every arm gets the same "
        "generator frames and trials, training frames, epochs, image size and replay per round)"]
    assert not (tmp_path / "loop").exists()


def test_an_unknown_generator_is_refused(tmp_path):
    from garage_exp.loop.app import cli

    r = run_in_process([f"dir={tmp_path}/loop", "arms.Q.sampler=annealing"], tmp_path, entry=cli)
    assert r.returncode == 2 and "arms.Q.sampler: 'annealing' is not a sampler of the search" in r.stderr


def test_a_round_draws_exactly_its_budget(tmp_path):
    from garage_exp.loop import budget
    from garage_exp.loop.steps import Trial

    def trial(k, difficulty, frames):
        d = tmp_path / str(k) / "dataset"
        (d / "images").mkdir(parents=True)
        (d / "data.yaml").write_text("names: {0: person}\n")
        for f in range(frames):
            (d / "images" / f"{f:04d}_front.png").write_bytes(b"")
        return Trial("s", k, "COMPLETE" if difficulty is not None else "PRUNED", difficulty, tmp_path / str(k), frames)

    found = [trial(0, 0.9, 5), trial(1, 0.2, 6), trial(2, 0.7, 4), trial(3, None, 3)]
    new = budget.joining(found, "failures", hard_below=0.4)
    assert [t.number for t in new] == [0, 2]  # confidence 0.1 and 0.3
    assert [t.number for t in budget.joining(found, "all", 0.4)] == [0, 1, 2, 3]
    assert budget.rendered(found) == 18
    frames, topped = budget.round_frames(new, found, 7, seed=1)
    assert len(frames) == len(set(frames)) == 7 and topped == 0
    assert frames == budget.round_frames(new, found, 7, seed=1)[0]
    frames, topped = budget.round_frames(new, found, 12, seed=1)  # 9 failure frames and the hardest other trial's 3
    assert len(frames) == 12 and topped == 3 and all("/1/" in str(f) for f in frames[9:])
    with pytest.raises(ValueError, match="fewer than train_frames=19"):
        budget.round_frames(new, found, 19, seed=1)
    # of the 12, the 9 of the two failures show a failure; the hardest other trial's 3 (confidence 0.8) do not
    assert budget.failure_frames(frames, found, 0.4) == 9
    every = budget.round_frames(budget.joining(found, "all", 0.4), found, 18, seed=1)[0]
    assert budget.failure_frames(every, found, 0.4) == 9  # a random arm's frames hold failures too
    assert budget.failure_frames(every, found, 0.95) == 15  # 0.1, 0.3 and 0.8 below 0.95: 5 + 4 + 6 frames


def fake_steps(monkeypatch, tmp_path):
    """Steps that write what the commands would (a study's trials with datasets, a training's result.json) without
    rendering or training; the evaluation and report are stubbed (their parts are tested on their own)."""
    from garage_exp.loop import app, evaluate, heldout, report, steps

    ran, studies = [], {}

    def arg(cmd, key):
        return next(a.split("=", 1)[1] for a in cmd if a.startswith(key + "="))

    def fake_run(cmd, log):
        ran.append(cmd)
        if "garage_exp.train" in cmd:
            out = Path(arg(cmd, "hydra.run.dir"))
            (out / "weights").mkdir(parents=True, exist_ok=True)
            (out / "weights" / "best.pt").write_text(arg(cmd, "name"))
            listing = Path(arg(cmd, "data").strip("[]")).with_suffix(".txt")
            n = len(listing.read_text().split())
            (out / "result.json").write_text(json.dumps({
                "weights": str(out / "weights" / "best.pt"), "model": str(out / "weights" / "best.pt"),
                "train_frames": n, "replay_frames": n, "val_frames": 3, "epochs": int(arg(cmd, "epochs")),
                "imgsz": int(arg(cmd, "imgsz"))}))
        elif "hydra/sweeper=search" in cmd:
            name, n = arg(cmd, "search.study"), int(arg(cmd, "search.trials"))
            budget = int(next((a.split("=")[1] for a in cmd if a.startswith("search.frames=")), 0))
            made = []
            for k in range(n):
                if budget and 4 * k >= budget:  # the search's frame budget (4 frames a trial): spent
                    break
                d = tmp_path / "fake" / name / str(k)
                (d / "dataset" / "images").mkdir(parents=True, exist_ok=True)
                (d / "dataset" / "data.yaml").write_text("names: {0: person}\n")
                for f in range(4):
                    (d / "dataset" / "images" / f"{f:04d}_front.png").write_bytes(b"")
                made.append(steps.Trial(name, k, "COMPLETE", 0.9 if k % 2 else 0.3, d, 4))
            studies[name] = made

    monkeypatch.setattr(steps, "run", fake_run)
    monkeypatch.setattr(steps, "trials", lambda cfg, name: studies.get(name, []))
    monkeypatch.setattr(steps, "study_done", lambda cfg, name, n, frames=0: name in studies)
    monkeypatch.setattr(heldout, "enqueue", lambda *a: None)
    monkeypatch.setattr(evaluate, "easy_suite", lambda *a: [])
    monkeypatch.setattr(evaluate, "score_all", lambda *a: pd.DataFrame())
    monkeypatch.setattr(app, "real_photos", lambda *a: [])
    monkeypatch.setattr(report, "write", lambda cfg, out, scores, photos, book, detectors, times, **kw: {
        "book": book, "detectors": detectors})
    return ran


def small(args: list[str], **values):
    """The loop's config with these overrides, and values set after (a dict such as `protocol` replaced whole)."""
    cfg = compose_cfg(*args, config="loop")
    for key, value in {"protocol": {}, **values}.items():
        cfg[key] = value
    return cfg


def test_rounds_chain_each_arms_detector_and_resume_without_rerunning(tmp_path, monkeypatch):
    """Round k searches and fine-tunes each arm's detector of round k-1 (round 1: D0), the arms with the same search
    seed per training seed; the failures accumulate in the arm's suite; a rerun runs nothing already done, and one
    more round runs only that round."""
    from garage_exp.loop.app import run_loop

    ran = fake_steps(monkeypatch, tmp_path)
    args = [f"dir={tmp_path / 'loop'}", "tracking.uri=sqlite:///x.db", "rounds=1", "seeds=[0,1]", "trials=6",
            "frames=14", "train_frames=8", "base_trials=4", "heldout_trials=3", "photos=false",
            "arms.Q.sampler=tpe"]
    out = run_loop(small(args))
    searches = [c for c in ran if "hydra/sweeper=search" in c]
    trainings = [c for c in ran if "garage_exp.train" in c]
    assert [next(a for a in c if a.startswith("search.study=")) for c in searches] == [
        "search.study=base", "search.study=heldout", "search.study=gen_R_r1_s0", "search.study=gen_T_r1_s0",
        "search.study=gen_Q_r1_s0", "search.study=gen_R_r1_s1", "search.study=gen_T_r1_s1", "search.study=gen_Q_r1_s1"]
    d0 = str(Path(compose_cfg(*args, config="loop").base).absolute())
    assert all(f"detector.models=[{d0}]" in c for c in searches[2:])  # round 1 searches D0
    assert all(f"base={d0}" in c and "bn_calibrate=64" in c and "warmup_bias_lr=0.0" in c for c in trainings)
    assert [c for c in searches[2:] if "search.seed=1000" in c] == searches[2:5]  # pairs by seed: one search seed
    assert all("search.frames=14" in c and "search.trials=6" in c for c in searches[2:])  # a frame budget, capped
    book = pd.DataFrame(out["book"])
    assert book.train_frames.tolist() == [8] * 6
    assert book.rendered_frames.tolist() == [16] * 6 and book.trials.tolist() == [4] * 6  # 4 trials: 16 >= 14
    assert book[book.arm == "R"].joined.tolist() == [4, 4] and book[book.arm == "T"].joined.tolist() == [2, 2]
    assert (book.failure_frames <= book.train_frames).all() and (book.failure_frames >= 0).all()

    ran.clear()
    run_loop(small(args))
    assert ran == []  # everything done: nothing rerun

    out = run_loop(small([a.replace("rounds=1", "rounds=2") for a in args]))
    studies = [next(a for a in c if a.startswith("search.study=")) for c in ran if "hydra/sweeper=search" in c]
    assert studies == [f"search.study=gen_{arm}_r2_s{s}" for s in (0, 1) for arm in "RTQ"]
    for c in ran:  # round 2 searches and fine-tunes the arm's own round-1 detector of the same seed
        name = next(a for a in c if a.startswith(("search.study=gen_", "name=")))
        arm, _, seed = name.split("_")[-3:] if "gen_" in name else name.split("=")[1].split("_")
        weights = tmp_path / "loop" / "train" / f"{arm}_r1_{seed}" / "weights" / "best.pt"
        assert f"detector.models=[{weights}]" in c or f"base={weights}" in c
    book = pd.DataFrame(out["book"])
    assert book[book["round"] == 2].suite_scenarios.tolist() == [8, 4, 4, 8, 4, 4]  # the suites grew


def test_a_real_photo_check_is_named_by_its_round_variant_seeds_and_mix():
    """One real-photo check per last round, variant, training seeds and mix: a seed added to a dir gets its own
    check rather than the refusal of a step made from other inputs; a one-seed dir keeps its names."""
    from garage_exp.loop.app import verify_suffix

    base = ["tracking.uri=sqlite:///x.db", "rounds=2"]
    assert verify_suffix(small([*base, "seeds=[0]", "wise=1.0"])) == "_r2"  # as before seeds were named
    one = verify_suffix(small([*base, "seeds=[0]", "wise=0.5"]))
    two = verify_suffix(small([*base, "seeds=[0,1]", "wise=0.5"]))
    assert one == "_r2_wise50" and two == "_r2_seeds0-1_wise50"
    assert verify_suffix(small([*base, "seeds=[0,1]", "wise=1.0", "variant=big"])) == "_r2_big_seeds0-1"


def test_each_generator_spends_its_frame_budget_or_the_loop_stops(tmp_path):
    """After a round, every arm's generator rendered at least its frames and less than one trial more; one that hit
    its cap of trials short of the budget stops the loop in one line (raise trials)."""
    from garage_exp.core.errors import JobFault
    from garage_exp.loop import budget
    from garage_exp.loop.steps import Trial

    def found(*frames):
        return [Trial("s", k, "COMPLETE", 0.5, None, f) for k, f in enumerate(frames)]

    budget.assert_equal_frames({"R": found(10, 26, 8), "Q": found(8, 8, 8, 8, 14)}, 44, "round 1, seed 0")
    budget.assert_equal_frames({"R": found(8)}, 0, "no frame budget: trials are the budget")
    with pytest.raises(JobFault, match="arm Q's generator rendered 16 frames in its 2 trials, short of its "
                                       "budget of 44: raise trials"):
        budget.assert_equal_frames({"R": found(26, 26), "Q": found(8, 8)}, 44, "round 1, seed 0")
    with pytest.raises(AssertionError, match="did not stop at its budget"):
        budget.assert_equal_frames({"T": found(26, 26, 26)}, 44, "round 1, seed 0")


def test_a_shortfall_found_after_rendering_is_exit_1_with_what_was_kept(tmp_path, monkeypatch):
    """Issue 47, item 3: a generator that rendered fewer frames than its budget at its cap of trials (a budget its
    trials could have reached, so not refused up front) stops the loop before its fine-tuning: one line, exit 1,
    the steps done so far kept under dir."""
    from garage_exp.loop import check
    from garage_exp.loop.app import cli

    ran = fake_steps(monkeypatch, tmp_path)  # 4 frames a trial: 2 trials render 8 of a budget of 14
    monkeypatch.setattr(check, "check_steps", lambda cfg: None)  # its steps' checks: test_loop.py, the corpus
    args = [f"dir={tmp_path / 'loop'}", f"tracking.uri=sqlite:///{tmp_path / 'x.db'}", "rounds=1", "seeds=[0]",
            "trials=2", "frames=14", "base_trials=4", "heldout_trials=3", "photos=false", "arms.Q.sampler=tpe",
            "~protocol.cpnco", "~protocol.cpra", "~protocol.crossing", "~protocol.crouch"]
    r = run_in_process(args, tmp_path, entry=cli)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and lines == [
        f"garage_exp.loop: round 1, seed 0: arm R's generator rendered 8 frames in its 2 trials, short of its budget "
        "of 14: raise trials (the generators' cap; in another dir or with variant=NAME, since a step is not rerun "
        f"with other inputs); the steps done so far are kept under {tmp_path / 'loop'}"], r.stderr
    assert not [c for c in ran if "garage_exp.train" in c]  # stopped before the arm's fine-tuning
    assert "base" in json.loads((tmp_path / "loop" / "commands.json").read_text())


def test_the_cost_model_adds_up():
    from garage_exp.loop import cost
    from garage_exp.loop.schema import ArmConf

    cfg = small(["rounds=1", "seeds=[0]", "base_trials=4", "heldout_trials=2", "trials=3", "frames=0", "train_frames=10",
                 "epochs=2", "replay_fraction=1.0", "val_fraction=0.5", "photos=true", "cost.search_s=20",
                 "cost.render_s_per_frame=1", "cost.trial_overhead_s=2", "cost.command_s=10",
                 "cost.train_s_per_image_epoch=0.5", "cost.val_s_per_image=0.1", "cost.detect_s_per_frame=0.1",
                 "cost.frames_per_trial=5", "cost.verify_s=4", "cost.load_s=3"],
                protocol={"p": ["case=crossing", "light=bright,dim"]}, arms={"R": ArmConf("random", "all")})
    parts = cost.estimate(cfg)
    assert parts["base data"] == 20 + 4 * (2 + 5)
    assert parts["held-out sample"] == 20 + 2 * 7
    assert parts["protocol suite"] == 10 + 2 * 7
    assert parts["generators"] == 20 + 3 * 7
    cfg.frames = 10  # a frame budget, crossed on average by half a trial's 5 frames: 12.5 frames, 2.5 trials
    assert cost.estimate(cfg)["generators"] == pytest.approx(20 + 12.5 * 1 + 2.5 * 2)
    assert parts["fine-tunings"] == pytest.approx(10 + 2 * 20 * 0.5 + 3 * 10 * 0.1)  # 10 val frames: half of 4 x 5
    assert parts["evaluation"] == pytest.approx(2 * (3 + 2 * 5 * 0.1) + 2 * 2 * 5 * 0.1)  # D0 and R's: both suites
    assert parts["real photos"] == 2 * (10 + 2 * 4)  # two sets (ultralytics' photos, the street set): D0 and R
    assert parts["total"] == pytest.approx(sum(v for k, v in parts.items() if k != "total"))


def test_the_shipped_loop_fits_its_budget():
    """conf/loop.yaml at its measured rates: at most 2.5 hours on the 2-core CPU it was sized on."""
    from garage_exp.loop import cost

    assert cost.estimate(compose_cfg(config="loop"))["total"] <= 2.5 * 3600


@pytest.fixture(scope="module")
def photos_dir(tmp_path_factory):
    from conftest import require

    require("models")
    import ultralytics

    return Path(ultralytics.__file__).parent / "assets"


def test_batchnorm_calibration_keeps_eval_outputs_and_makes_train_mode_agree(photos_dir):
    """The folded COCO yolo11n: calibrated on two photos, its eval outputs stay (within float error) and its train
    mode (batch statistics, as fine-tuning sees them) computes what eval mode does; uncalibrated, train mode is far
    off - the first fine-tuning step would wreck it."""
    import torch

    from garage_exp.train.calibrate import calibrate_model, letterboxed

    base = Path(__file__).resolve().parents[1] / ".." / "shared" / "models" / "yolo11n_fp32_from_int8.pt"
    images = [photos_dir / "bus.jpg", photos_dir / "zidane.jpg"]
    x = torch.from_numpy(__import__("numpy").stack([letterboxed(p, 128) for p in images]))

    def features(model, train: bool):
        """The detection head's inputs; a train-mode pass runs on a copy (it updates the running statistics)."""
        model = copy.deepcopy(model) if train else model
        got = {}
        head = model.model[-1]
        handle = head.register_forward_pre_hook(lambda m, inputs: got.setdefault("x", [t.clone() for t in inputs[0]]))
        model.train(train)
        with torch.no_grad():
            model(x)
        handle.remove()
        return got["x"]

    def gap(a, b):
        return max(float((p - q).abs().max() / (q.abs().max() + 1e-9)) for p, q in zip(a, b))

    model = torch.load(str(base), map_location="cpu", weights_only=False)["model"].float()
    before = features(model, False)
    assert gap(features(model, True), before) > 0.5  # uncalibrated: train mode is another network
    model.eval()
    assert calibrate_model(model, images, 128) == 81
    assert gap(features(model, False), before) < 1e-3  # eval outputs unchanged
    assert gap(features(model, True), before) < 1e-3  # train mode on the calibration batch: the same


def test_the_report_pairs_seeds_and_corrects_the_whole_family():
    """Per round and arm: the seeds' mean failure rate (D0: its Wilson interval); after the last round one Holm
    family: the pair of arms and each arm against D0 on the failure rate, the protocol and the photos' recall."""
    from garage_exp.loop import report, stats

    rows = [{"arm": "D0", "round": 0, "seed": -1, "suite": "heldout", "failures": 8, "scenarios": 16, "per_100": 50.0},
            {"arm": "D0", "round": 0, "seed": -1, "suite": "protocol", "fair_recall": 0.5}]
    for seed, (r, t) in enumerate([(6, 4), (7, 4), (5, 2)]):
        for arm, f in (("R", r), ("T", t)):
            rows += [{"arm": arm, "round": 1, "seed": seed, "suite": "heldout", "failures": f, "scenarios": 16,
                      "per_100": 100 * f / 16},
                     {"arm": arm, "round": 1, "seed": seed, "suite": "protocol", "fair_recall": 0.5 + 0.1 * seed}]
    scores = pd.DataFrame(rows)
    photos = pd.DataFrame([{"arm": a, "round": k, "seed": s, "set": "photos", "recall": 6 / 7}
                           for a, k, s in [("D0", 0, -1), ("R", 1, 0), ("R", 1, 1), ("R", 1, 2), ("T", 1, 0),
                                           ("T", 1, 1), ("T", 1, 2)]])
    table = report.round_table(scores)
    d0 = table[table.arm == "D0"].iloc[0]
    assert (d0.low, d0.high) == pytest.approx(tuple(100 * v for v in stats.wilson(8, 16)))
    r = table[table.arm == "R"].iloc[0]
    assert r.per_100 == pytest.approx(37.5) and (r.pooled_failures, r.pooled_scenarios) == (18, 48)
    family = report.comparisons(scores, photos, ["R", "T"], 1)
    assert list(zip(family.metric, family.a, family.b)) == [
        ("failures per 100 (held-out)", "R", "T"), ("failures per 100 (held-out)", "R", "D0"),
        ("protocol recall", "R", "D0"), ("real-photo recall", "R", "D0"), ("failures per 100 (held-out)", "T", "D0"),
        ("protocol recall", "T", "D0"), ("real-photo recall", "T", "D0")]
    assert family["diff"].iloc[0] == pytest.approx(100 * 8 / 3 / 16)  # R - T: 2, 3, 3 failures of 16
    assert family.p_holm.tolist() == pytest.approx(stats.holm(family.p.tolist())[1], nan_ok=True)
    assert family.p.iloc[3] != family.p.iloc[3]  # the photos' recall: the same for every seed and D0, no spread: no test
    # the question in seeds: 20 % of R's mean rate (37.5 per 100: 7.5), at Holm's first step over the family
    estimate = report.power(scores, ["R", "T"], 1, comparisons=len(family))
    sd = estimate["sd_of_paired_differences"]["R-T"]
    assert sd == pytest.approx(pd.Series([100 * 2 / 16, 100 * 3 / 16, 100 * 3 / 16]).std())
    assert estimate["seeds_needed_20pct_holm"]["R-T"] == math.ceil(
        stats.seeds_needed(sd, 0.2 * 37.5, alpha=0.05 / len(family)))
    alone = report.power(scores, ["R", "T"], 1, comparisons=1)["seeds_needed_20pct_holm"]["R-T"]
    assert alone < estimate["seeds_needed_20pct_holm"]["R-T"]  # Holm's first step over 7 asks for more seeds


def test_the_held_out_cells_say_which_failure_kinds_training_removed(tmp_path):
    """Each held-out scenario's cell is measured from its own frame table (its first fair frame); per cell and
    detector group, the share of its scenarios failed (seeds pooled); the cells an arm still fails are listed;
    a heatmap per group is drawn."""
    from omegaconf import OmegaConf

    from garage_exp.loop import cells
    from garage_exp.loop.steps import Trial
    from garage_exp.search.archive import Grid
    from garage_exp.search.schema import DescriptorConf, SearchConf

    search = OmegaConf.structured(SearchConf(descriptors=[DescriptorConf("kind", values=["car", "adult", "child"]),
                                                          DescriptorConf("visible", edges=[0.0, 0.9, 1.0])]))
    rows = {0: ("vehicle", "car", 0.6), 1: ("person", "child", 0.95), 2: ("person", "adult", 0.7),
            3: ("vehicle", "car", 0.2)}  # scenario 3: never fairly visible (0.2 < min_visible)
    held = []
    for number, (kind, target, visible) in rows.items():
        out = tmp_path / str(number)
        out.mkdir()
        pd.DataFrame({"shot": [0, 1], "camera": "front", "target_kind": kind, "target": target,
                      "distance": [12.0, 10.0], "visible_fraction": [0.1, visible], "box_height": 60.0,
                      "truncation": 0.0}).to_csv(out / "frames.csv", index=False)
        held.append(Trial("heldout", number, "COMPLETE", None, out, 2))
    held.append(Trial("heldout", 4, "FAIL", None, None, 0))
    found = cells.cells_of(held, search)
    assert found == {0: (0, 0), 1: (2, 1), 2: (1, 0)}  # the first FAIR frame's values (not shot 0's 0.1)
    scores = pd.DataFrame([
        {"arm": "D0", "round": 0, "seed": -1, "suite": "heldout", "failed": [0, 1, 2]},
        {"arm": "Q", "round": 2, "seed": 0, "suite": "heldout", "failed": [0]},
        {"arm": "Q", "round": 2, "seed": 1, "suite": "heldout", "failed": [0, 2]},
        {"arm": "Q", "round": 2, "seed": 1, "suite": "easy", "failed": [1]}])  # another suite: not counted
    grid = Grid(search.descriptors)
    table = cells.cell_table(scores, found, grid)
    q = table[table.arm == "Q"].set_index("cell")
    assert q.loc["car | 0-0.9"].failed_share == 1.0 and q.loc["adult | 0-0.9"].failed_share == 0.5
    assert q.loc["child | 0.9-1"].failures == 0 and q.loc["child | 0.9-1"].detectors == 2
    assert cells.resisted(table, "Q", 2) == ["car | 0-0.9", "adult | 0-0.9"]
    assert cells.resisted(table, "D0", 0) == ["car | 0-0.9", "adult | 0-0.9", "child | 0.9-1"]
    paths = cells.draw(table, grid, tmp_path, 2)
    assert [p.name for p in paths] == ["cells_D0.png", "cells_Q.png"] and all(p.stat().st_size > 0 for p in paths)


def test_wise_mixes_weights_in_the_tuned_models_batchnorm_statistics():
    """WiSE-FT (train/wise.py): alpha 0 computes what the base computes though the tuned model's BatchNorms hold
    other statistics; alpha 1 is the tuned model; alpha 0.5 averages the convolutions; another architecture is
    refused."""
    import torch

    from garage_exp.train.wise import mix_models

    torch.manual_seed(0)

    def net():
        return torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4), torch.nn.ReLU(),
                                   torch.nn.Conv2d(4, 2, 1))

    base, tuned = net().eval(), net().eval()
    with torch.no_grad():  # each model's statistics and affine its own (the base's not the identity either)
        for bn in (base[1], tuned[1]):
            bn.running_mean.uniform_(-1, 1), bn.running_var.uniform_(0.5, 2)
            bn.weight.uniform_(0.5, 2), bn.bias.uniform_(-1, 1)
    x = torch.rand(2, 3, 8, 8)

    def mixed(alpha):
        return mix_models(copy.deepcopy(base), copy.deepcopy(tuned), alpha)

    with torch.no_grad():
        assert torch.allclose(mixed(0.0)(x), base(x), atol=1e-5)
        assert not torch.allclose(tuned(x), base(x), atol=1e-2)
        one = mixed(1.0)
        assert all(torch.equal(a, b) for a, b in zip(one.state_dict().values(), tuned.state_dict().values()))
        half = mixed(0.5)
    assert torch.allclose(half[0].weight, (base[0].weight + tuned[0].weight) / 2)
    assert torch.equal(half[1].running_var, tuned[1].running_var)
    with pytest.raises(ValueError, match="differ in architecture"):
        mix_models(torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3)), net(), 0.5)


def test_wise_scores_a_variants_training_again_without_training(tmp_path, monkeypatch):
    """`wise=0.5` on a finished loop: nothing searched or trained again; every round's detector is scored as its
    mix with D0 (made once), D0 as it is, under the mix's own results dir; a share outside 0-1 is one line."""
    from garage_exp.loop import app, report
    from garage_exp.train import wise

    ran = fake_steps(monkeypatch, tmp_path)
    mixes, written = [], {}
    monkeypatch.setattr(wise, "interpolate", lambda base, tuned, alpha, out: mixes.append((base, tuned, alpha))
                        or out.write_text("mix") or out)
    monkeypatch.setattr(wise, "validate", lambda weights, data, imgsz: mixes.append(imgsz) or {
        "map50": 0.5, "recall": 0.4, "precision": 0.6})
    monkeypatch.setattr(report, "write", lambda cfg, out, scores, photos, book, detectors, times, **kw:
                        written.update(out=out, detectors=detectors))
    args = [f"dir={tmp_path / 'loop'}", "tracking.uri=sqlite:///x.db", "rounds=1", "seeds=[0]", "trials=6",
            "frames=14", "train_frames=8", "base_trials=4", "heldout_trials=3", "photos=false"]
    app.run_loop(small(args))
    ran.clear()
    app.run_loop(small([*args, "wise=0.5"]))
    assert ran == [] and written["out"] == tmp_path / "loop" / "results_wise50"
    d0 = str(Path(compose_cfg(*args, config="loop").base).absolute())
    assert mixes[1::2] == [320] * 3  # validated at the fine-tuning's image size
    mixes = mixes[::2]
    assert sorted(m[1].parts[-3] for m in mixes) == ["Q_r1_s0", "R_r1_s0", "T_r1_s0"]
    assert all(str(m[0]) == d0 and m[2] == 0.5 for m in mixes)
    weights = {n: Path(d["weights"]).name for n, d in written["detectors"].items()}
    assert weights == {"D0": Path(d0).name, "R_r1_s0": "wise50.pt", "T_r1_s0": "wise50.pt", "Q_r1_s0": "wise50.pt"}
    assert {n: d.get("mixed_validation") for n, d in written["detectors"].items()} == {
        "D0": None, **{f"{a}_r1_s0": {"alpha": 0.5, "map50": 0.5, "recall": 0.4} for a in "RTQ"}}
    made = len(mixes)
    app.run_loop(small([*args, "wise=0.5"]))
    assert len(mixes) == made  # made once
    for value, line in (("1.5", "wise: 1.5 (the fine-tuned weights' share: 0 D0, 1 as trained) is outside 0-1"),
                        ("0.504", "wise: 0.504: a whole percentage (0.5, 0.25, ...)")):
        r = run_in_process([f"dir={tmp_path}/other", f"wise={value}"], tmp_path, entry=app.cli)
        assert r.returncode == 2 and r.stderr.strip().splitlines() == [f"garage_exp.loop: {line}"]
    assert not (tmp_path / "other").exists()
