"""`python -m garage_exp.loop` (issues 22 and 39): the arms' equal budgets (configured and trained), the failure
count, the held-out sample's determinism, the rounds' bookkeeping and resume, the statistics on known numbers,
the cost model, a step's result reused only for the same inputs, and the command line's refusals and signals."""

from pathlib import Path

import pytest
from conftest import compose_cfg, run_in_process

# Until the archive sampler (issue 39, item 1) is merged, the search refuses it: the Q arm searches with TPE here.
NO_ARCHIVE = ["arms.Q.sampler=tpe"]


def test_the_arms_budgets_are_equal(tmp_path):
    """The random arm draws exactly the hard arm's frame count; trainings that differ in any budget are refused."""
    from garage_exp.loop import budget

    pool = [tmp_path / f"s{k // 10}" / "images" / f"{k % 10:04d}_front.png" for k in range(60)]
    drawn = budget.draw_frames(pool, 23, seed=0)
    assert len(drawn) == len(set(drawn)) == 23 and drawn == budget.draw_frames(pool, 23, seed=0)
    with pytest.raises(ValueError, match="fewer than the 61 asked"):
        budget.draw_frames(pool, 61, seed=0)
    h = {"train_frames": 23, "replay_frames": 12, "val_frames": 40, "epochs": 8, "imgsz": 320}
    budget.assert_equal_budget({"R": h, "T": dict(h), "Q": dict(h)})
    for key in budget.BUDGET_KEYS:
        with pytest.raises(AssertionError, match=rf"\(R, Q\): \{{'{key}'"):
            budget.assert_equal_budget({"R": h, "T": dict(h), "Q": {**h, key: h[key] + 1}})


def test_an_arms_own_overrides_reach_its_generator_alone_and_leave_every_other_command_as_it_was(tmp_path,
                                                                                                   monkeypatch):
    """arms.ARM.overrides (its sampler's method, e.g. curiosity's parents) end that arm's search command; an arm
    without them, and every shared step, keeps the command it had before they existed (so a done step is reused)."""
    from garage_exp.loop import steps

    cfg = compose_cfg(f"dir={tmp_path}", "arms.Q.overrides=['search.archive.parents=curiosity']", config="loop")
    assert list(cfg.arms.Q.overrides) == ["search.archive.parents=curiosity"] and not cfg.arms.R.overrides
    plain = steps.search_command(cfg, "gen_Q_r1_s0", [], 40, "archive", 1000)
    own = steps.search_command(cfg, "gen_Q_r1_s0", [], 40, "archive", 1000, extra=list(cfg.arms.Q.overrides))
    assert own == plain + ["search.archive.parents=curiosity"]
    assert steps.search_command(cfg, "gen_R_r1_s0", [], 40, "random", 1000, extra=[]) == \
        steps.search_command(cfg, "gen_R_r1_s0", [], 40, "random", 1000)
    # the loop's check of its steps composes the Q generator's search with them, and no other step's
    from types import SimpleNamespace

    from garage_exp.loop import check

    made = []
    real = steps.search_command
    monkeypatch.setattr(steps, "search_command", lambda *a, **k: made.append(real(*a, **k)) or made[-1])
    monkeypatch.setattr(check, "_checked", lambda cfg, step, fn: SimpleNamespace(fewest_frames=10**6, most_frames=10**6))
    check.check_steps(cfg)
    studies = {next(w for w in c if w.startswith("search.study=")): c for c in made}
    assert studies["search.study=gen_Q"][-1] == "search.archive.parents=curiosity"
    assert [c for c in made if "search.archive.parents=curiosity" in c] == [studies["search.study=gen_Q"]]
    # an arm whose sampler is not the archive has no method to set: refused, not ignored
    from garage_exp.core.errors import GarageError
    from garage_exp.loop.app import check_loop

    with pytest.raises(GarageError, match="arm R's sampler is random"):
        check_loop(compose_cfg(f"dir={tmp_path}", "arms.R.overrides=['search.archive.parents=curiosity']",
                               config="loop"))


def test_failures_per_100_trials_count_only_hard_fair_trials():
    from garage_exp.loop import budget
    from garage_exp.loop.steps import Trial
    from garage_exp.results.stats import wilson

    trials = [Trial("s", 0, "COMPLETE", 0.9, None), Trial("s", 1, "COMPLETE", 0.5, None),
              Trial("s", 2, "PRUNED", None, None), Trial("s", 3, "COMPLETE", 0.61, None),
              Trial("s", 4, "RUNNING", None, None)]
    assert budget.failures(trials, hard_below=0.4) == (2, 4)  # confidence 0.1 and 0.39; the pruned trial counts
    low, high = wilson(0, 30)
    assert low == 0.0 and 0.10 < high < 0.13  # Wilson's interval is not empty at 0 / 30
    low, high = wilson(15, 30)
    assert low < 0.5 < high and abs((low + high) / 2 - 0.5) < 1e-9


def test_the_loop_refuses_a_held_out_plan_it_trains_on(tmp_path):
    """Held-out means another plan: the loop stops before anything runs."""
    from garage_exp.loop.app import cli

    r = run_in_process([f"dir={tmp_path}/loop", "eval_plan=research", *NO_ARCHIVE], tmp_path, entry=cli)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "garage_exp.loop: eval_plan: 'research' is also a training plan: held-out data must come from another plan"]
    assert not (tmp_path / "loop").exists()


def test_the_loop_never_reuses_a_step_made_by_another_command(tmp_path):
    """A loop rerun with other settings in the same dir is refused, not answered with the old step's result."""
    from omegaconf import OmegaConf

    from garage_exp.core.errors import GarageError
    from garage_exp.loop.app import Loop

    loop = Loop(OmegaConf.create({"dir": str(tmp_path)}))
    assert loop.reuse("arm", ["train", "epochs=6"], done=False) is False  # not done: run it
    assert loop.reuse("arm", ["train", "epochs=6"], done=True) is True  # done by the same command: reuse
    with pytest.raises(GarageError, match="epochs=6 -> 8"):
        Loop(OmegaConf.create({"dir": str(tmp_path)})).reuse("arm", ["train", "epochs=8"], done=True)


def test_the_loop_decides_reuse_by_every_steps_full_inputs(tmp_path, monkeypatch, capsys):
    """Issue 31, item 7: a study begun with 4 trials is not resumed with 5, and a training whose data list now
    holds another split is not reused, finished or not; the refusal is one line and runs nothing."""
    from garage_exp.core.errors import GarageError
    from garage_exp.loop import steps
    from garage_exp.loop.app import Loop

    ran = []

    def fake_run(cmd, log):
        ran.append(cmd)
        if "garage_exp.train" in cmd:
            out = Path(next(a for a in cmd if a.startswith("hydra.run.dir="))[len("hydra.run.dir="):])
            out.mkdir(parents=True, exist_ok=True)
            (out / "result.json").write_text("{}")

    monkeypatch.setattr(steps, "run", fake_run)
    monkeypatch.setattr(steps, "trials", lambda cfg, study: [])
    monkeypatch.setattr(steps, "study_done", lambda cfg, study, n, frames=0: False)  # interrupted: 4 of 4 never finished
    cfg = compose_cfg(f"dir={tmp_path}", "tracking.uri=sqlite:///x.db", config="loop")
    study = ("base", ["plan=research"], 4, "qmc", 0)
    loop = Loop(cfg)
    loop.step("base data", lambda: loop.study(*study))
    loop.step("base data", lambda: loop.study(*study))  # the same inputs: resumed
    assert len(ran) == 2
    with pytest.raises(GarageError, match=r"'base' made from other inputs \(search.trials=4 -> 5\)"):
        fresh = Loop(cfg)
        fresh.step("base data", lambda: fresh.study("base", ["plan=research"], 5, "qmc", 0))
    data = tmp_path / "data" / "base_train.yaml"
    data.parent.mkdir()
    data.write_text("train: [a]\n")
    kw = {"data": [data], "val": [data], "base": "yolov8n.yaml", "epochs": 1, "seed": 0, "lr0": 0.01}
    loop.step("D0", lambda: loop.train("D0", **kw))
    loop.step("D0", lambda: loop.train("D0", **kw))  # finished, same inputs: reused
    assert len(ran) == 3
    data.write_text("train: [b]\n")  # another split (val_fraction=...) under the same path
    capsys.readouterr()
    with pytest.raises(GarageError, match=r"base_train.yaml changed\); give this run another dir"):
        Loop(cfg).train("D0", **kw)
    assert len(ran) == 3 and capsys.readouterr().out == ""


def test_sigterm_stops_the_loop_and_its_running_step(tmp_path, monkeypatch):
    """SIGTERM to the loop: exit 143 with one line saying how to go on (the loop had no handler: it died at once);
    the running step, a child process, gets the SIGTERM too and stops as its command does (its run KILLED), instead
    of being killed with its run left RUNNING."""
    import sys

    from garage_exp.loop import steps
    from garage_exp.loop.app import cli

    child = tmp_path / "child.py"
    child.write_text("import signal, sys, time\n"
                     "signal.signal(signal.SIGTERM, lambda s, f: (open(sys.argv[1], 'w').write(str(s)), sys.exit(143)))\n"
                     "open(sys.argv[2], 'w').write('up')\n"
                     "time.sleep(60)\n")
    got, up = tmp_path / "got", tmp_path / "up"

    def step(cmd, log):  # a step that runs, then the loop gets SIGTERM
        import threading

        def kill_when_up():
            import os
            import signal
            import time

            while not up.exists():
                time.sleep(0.05)
            os.kill(os.getpid(), signal.SIGTERM)

        threading.Thread(target=kill_when_up, daemon=True).start()
        real_run([sys.executable, str(child), str(got), str(up)], log)

    real_run = steps.run
    monkeypatch.setattr(steps, "run", step)
    monkeypatch.setattr("garage_exp.loop.check.check_steps", lambda cfg: None)  # the shipped steps' checks: seconds
    r = run_in_process([f"dir={tmp_path / 'loop'}", *NO_ARCHIVE], tmp_path, entry=cli)
    assert r.returncode == 143, r.stderr[-2000:]
    assert r.stderr.strip().splitlines()[-1] == ("garage_exp.loop: terminated (SIGTERM); rerun the same command to go "
                                                  "on where it stopped")
    assert got.read_text() == "15"  # the step got SIGTERM and finished its handler
