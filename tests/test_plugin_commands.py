"""Issue 47, item 1: a user's registrations ($GARAGE_EXP_PLUGINS) are seen by every command before it checks
anything, not only inside its jobs: a search whose sweeper checks the objective and the detector's entries before
any trial, the loop whose check composes its steps before the first, the gym. One temporary plugin module, as a
user writes it, registers an objective and a detector entry kind; each command uses them."""

from __future__ import annotations

import os
import sys

import optuna
import pytest
from conftest import require, run_app, run_in_process

from garage_exp.perception.detect.kinds import KINDS as ENTRY_KINDS
from garage_exp.search.objectives import OBJECTIVES

PLUGIN = "issue47_plugin"
PLUGIN_MODULE = '''
"""A detector entry kind `half:` (a car box over the frame's middle half, at the score it names) and an
objective `missrate` (the share of the target's frames the detector missed)."""
import numpy as np

from garage_exp.perception.detect.base import Detections, Entry
from garage_exp.perception.detect.kinds import register_entry_kind
from garage_exp.search.objectives import NOT_VISIBLE, Objective, register_objective


@register_entry_kind("half", prefix="half:")
class Half(Entry):
    kind = "half"

    def __init__(self, entry, settings):
        super().__init__(entry, settings)
        self.name, self.score = "half", float(self.entry[len("half:"):])

    def check(self, intrinsics=None):
        self.classes = ("car",)

    def detect(self, frames, intrinsics):
        return [Detections(np.array([[f.shape[1] / 4, f.shape[0] / 4, f.shape[1] * 3 / 4, f.shape[0] * 3 / 4]],
                                    np.float32), np.array([self.score], np.float32), ["car"]) for f in frames]


def judge(result, attrs):
    return None if result.recall is None else [1.0 - result.recall]


register_objective(Objective("missrate", ("missrate",), ("maximize",), judge,
                             lambda values, attrs: f"missed {values[0]:.2f}", NOT_VISIBLE))
'''
# One trial of two 320x240 frames on the tiny plan, scored by the plugin's entry, judged by its objective.
SEARCH = ["-m", "hydra/sweeper=search", "plan=tiny", "search.trials=1", "search.objective=missrate",
          "detector.models=[half:0.7]", "light.intensity=interval(0.5,1.0)", "case.motion.start=5",
          "case.motion.end=4", "case.motion.step=1", "camera.width=320", "camera.height=240",
          "palette.target_colours=[black]"]
# The loop's estimate (every step checked, nothing run): a search space of one interval on the tiny plan, the
# plugin's entry as the detector (base is a model YAML: no .pt replaces it), no protocol, one arm.
LOOP = ["estimate=true", "base=yolov8n.yaml", "train_plans=[tiny]", "eval_plan=research", "rounds=1", "seeds=[0]",
        "space.params=['light.intensity=interval(0.5,1.0)']",
        "fixed=['case.motion.step=4.0','detector.models=[half:0.7]']",
        "~protocol.cpnco", "~protocol.cpra", "~protocol.crossing", "~protocol.crouch", "~arms.T", "~arms.Q", "frames=0"]


@pytest.fixture
def plugin(tmp_path):
    """The plugin module in a folder of its own, and the environment naming it; its registrations go after."""
    before = (list(ENTRY_KINDS), dict(OBJECTIVES))
    folder = tmp_path / "plugins"
    folder.mkdir()
    (folder / f"{PLUGIN}.py").write_text(PLUGIN_MODULE)
    yield {"GARAGE_EXP_PLUGINS": PLUGIN, "PYTHONPATH": os.pathsep.join(
        filter(None, [str(folder), os.environ.get("PYTHONPATH")]))}
    ENTRY_KINDS[:] = before[0]
    OBJECTIVES.clear()
    OBJECTIVES.update(before[1])
    sys.modules.pop(PLUGIN, None)


def stores(tmp_path) -> list[str]:
    return [f"search.storage=sqlite:///{tmp_path / 'optuna.db'}", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"]


@pytest.mark.render
def test_a_search_uses_a_plugins_objective_and_entry_kind(plugin, tmp_path):
    require("vulkan", "vehicles")
    r = run_app([*SEARCH, *stores(tmp_path)], tmp_path, env=plugin)
    assert r.returncode == 0, r.stderr[-3000:]
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    (name,) = optuna.get_all_study_names(storage)
    (trial,) = optuna.load_study(study_name=name, storage=storage).trials
    assert trial.state == optuna.trial.TrialState.COMPLETE, trial.user_attrs
    assert 0.0 <= trial.values[0] <= 1.0 and trial.user_attrs["frames"] == 2


def test_without_the_plugin_the_search_is_refused_before_any_trial(tmp_path):
    """The same command without $GARAGE_EXP_PLUGINS: one line naming the objective, exit 2, nothing written."""
    r = run_app([*SEARCH, *stores(tmp_path)], tmp_path, fresh_store=True)
    assert r.returncode == 2 and "unknown objective 'missrate'" in r.stderr, r.stderr[-3000:]
    assert not (tmp_path / "sweep").exists() and not (tmp_path / "optuna.db").exists()


def test_the_loop_checks_its_steps_with_the_plugins_kinds(plugin, tmp_path):
    """The loop's check composes its searches before the first step: the plugin's entry kind is known there;
    without the plugin the same estimate is refused in one line naming the loop's `fixed`."""
    from garage_exp.loop.app import cli

    args = [*LOOP, f"dir={tmp_path / 'loop'}"]
    r = run_in_process(args, tmp_path, env=plugin, entry=cli)
    assert r.returncode == 0 and "garage_exp.loop: estimate:" in r.stdout, r.stderr[-3000:]
    sys.modules.pop(PLUGIN, None)
    ENTRY_KINDS[:] = [k for k in ENTRY_KINDS if k.name != "half"]
    r = run_in_process(args, tmp_path, entry=cli)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("garage_exp.loop: fixed: "), r.stderr
    assert "half:0.7" in lines[0]
    assert not (tmp_path / "loop").exists()


def test_the_gym_builds_its_environment_with_the_plugins_entry_kind(plugin, tmp_path, monkeypatch):
    """The gym's environment preflights its job with the plugin's detector entry (its episode is not run)."""
    from garage_exp.gym import app

    seen = []
    monkeypatch.setattr(app, "run_check", lambda cfg, env: seen.append(list(env.checked_detector.names)))
    args = ["mode=check", "detector.models=[half:0.7]", "camera.width=320", "camera.height=240",
            f"hydra.run.dir={tmp_path / 'gym'}", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"]
    r = run_in_process(args, tmp_path, env=plugin, entry=app.cli)
    assert r.returncode == 0 and seen == [["half"]], r.stderr[-3000:]
