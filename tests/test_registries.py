"""The extension points' registries (issue 32, item 3): a new search objective or camera model is one entry, and
everything that judges, checks, words or renders it reads that entry (no name compared elsewhere).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import optuna
import pytest
from omegaconf import OmegaConf
from optuna.trial import TrialState

from garage_exp.core.errors import GarageError
from garage_exp.core.plain import typed
from garage_exp.scene import lenses
from garage_exp.scene.camera import check_camera, rig_specs
from garage_exp.scene.schema import CameraRigConf
from garage_exp.search import objectives
from garage_exp.search.loop import line, outcome

SUMMARY = {"visible_fraction_mean": 0.5, "fair_frames": 4, "frames": 10, "fair_difficulty": 0.3,
           "fair_recall": 0.75, "run_id": "r", "output_dir": "/x"}


@pytest.fixture
def recall_objective(monkeypatch):
    """An objective of the test's own: 1 - the fair recall, minimised the other way round, no pre-screen."""
    def judge(result, attrs):
        return None if attrs["recall"] is None else [1.0 - attrs["recall"]]

    goal = objectives.Objective("missed", ("missed",), ("minimize",), judge,
                                lambda values, attrs: f"missed {values[0]:.2f}", "no recall to judge",
                                needs=lambda job: None if job.case.name == "3" else "needs case 3")
    monkeypatch.setitem(objectives.OBJECTIVES, "missed", goal)
    return goal


def search_node(**keys):
    from garage_exp.search.schema import SearchConf

    return OmegaConf.merge(OmegaConf.structured(SearchConf), keys)


def test_a_new_objective_is_one_entry_that_judges_words_and_checks_its_trials(recall_objective):
    from garage_exp.search.study import check_search

    done = outcome(SUMMARY, "missed")
    assert done.state == TrialState.COMPLETE and done.values == [0.25]
    assert line(0, done, 3, "missed") == "garage_exp: trial 0 (1 of 3): missed 0.25"
    pruned = outcome({**SUMMARY, "fair_recall": math.nan}, "missed")
    assert pruned.state == TrialState.PRUNED and pruned.attrs["infeasible"]
    assert line(1, pruned, 3, "missed") == "garage_exp: trial 1 (2 of 3): no recall to judge: infeasible"
    check_search(search_node(objective="missed"))
    # no cheap look of its own: the pre-screen is refused for it, naming those that have one
    with pytest.raises(GarageError, match="search.prescreen.level: the pre-screen serves one objective "
                                          r"\(difficulty or late\), not missed"):
        check_search(search_node(objective="missed", prescreen={"level": "truth"}))
    job = OmegaConf.create({"case": {"name": "1"}})
    assert recall_objective.needs(job) == "needs case 3"


def test_the_shipped_objectives_say_what_they_need_and_whether_they_screen():
    assert [o.name for o in objectives.OBJECTIVES.values() if o.screen] == ["difficulty", "late"]
    assert [o.name for o in objectives.OBJECTIVES.values() if o.multi] == ["pareto"]
    assert {o.gym: o.verdict for o in objectives.gym_objectives().values()} == {"hard": "hard_fair", "late": "late"}
    rig = OmegaConf.create({"name": "front", "cameras": [{"name": "front", "model": "pinhole"}]})
    job = OmegaConf.create({"case": {"name": "slots", "slots": True}, "camera": rig})
    assert "needs a slot case on a fisheye rig" in objectives.objective("slots").needs(job)
    job.camera.cameras[0].model = "fisheye"
    assert objectives.objective("slots").needs(job) is None


def test_the_report_ranks_by_the_direction_the_study_was_made_with(recall_objective):
    """sweep.ranked put the highest value first whatever the study's direction."""
    from garage_exp.search.sweep import ranked

    study = optuna.create_study(directions=["minimize"])
    for value in (0.5, 0.1, 0.9):
        trial = study.ask()
        study.tell(trial, value)
    assert [t.values[0] for t in ranked(study)] == [0.1, 0.5, 0.9]


def fisheye_rig(model: str):
    """A one-camera rig, typed as the scene builder is handed it (run.spec.scene_spec)."""
    return typed(CameraRigConf, {"name": "test", "roof": True, "view": "raw", "cameras": [
        {"name": "front", "x": 0.0, "y": 0.0, "z": 0.3, "yaw": 0.0, "pitch": 0.0, "fovy": 60.0, "width": 64,
         "height": 48, "model": model, "fov": 190.0, "k": [-0.0417, 0.0005, 0.0, 0.0]}]})


def test_a_new_camera_model_is_one_entry_the_check_specs_and_renderer_read(monkeypatch):
    from garage_exp.scene.lenses import Fisheye, lens_of

    wide = type("Wide", (Fisheye,), {"bev": False, "model": "wide"})  # the fisheye lens, not stitched into a BEV
    monkeypatch.setitem(lenses.LENSES, "wide", wide)
    rig = fisheye_rig("wide")
    check_camera(rig)
    spec = rig_specs(rig, (4.77, 1.96, 1.5))[0]
    assert spec.model == "wide" and spec.fisheye and spec.fov == 190.0 and spec.k[0] == -0.0417
    assert isinstance(lens_of(spec), Fisheye)
    assert not lenses.rig_has(rig, "bev") and lenses.rig_has(fisheye_rig("fisheye"), "bev")
    # its own check runs: a lens that folds its image back is refused at its place
    rig.cameras[0].k = [-1.0, 0.0, 0.0, 0.0]
    with pytest.raises(GarageError, match="camera.cameras.0.k: coefficients .* fold the image back"):
        check_camera(rig)
    # and the KITTI export's pinhole calibration asks the model, not its name
    with pytest.raises(GarageError, match="camera.view: dataset=true writes KITTI's pinhole calibration"):
        check_camera(fisheye_rig("wide"), dataset=True)


def test_a_pinhole_camera_keeps_no_lens_fields_and_an_unknown_model_is_refused():
    rig = fisheye_rig("pinhole")
    spec = rig_specs(rig, (4.77, 1.96, 1.5))[0]
    assert not spec.fisheye and spec.fov == 0.0 and spec.k == (0.0, 0.0, 0.0, 0.0) and spec.view == "raw"
    with pytest.raises(GarageError, match=r"camera.cameras.0.model: unknown camera model 'orthographic' \(pinhole "
                                          r"\| fisheye\)"):
        check_camera(fisheye_rig("orthographic"))
    assert np.isclose(lenses.FISHEYE_FOV_RANGE[1], 200.0)


def test_each_node_is_registered_beside_its_owner_and_core_names_no_layer_above_it():
    """Item 4: a node's dataclass is declared and registered in the layer that owns it; core declares none and
    names no module above it (no dotted strings); the experiment's Config is assembled from the registrations."""
    import ast
    from pathlib import Path

    from garage_exp import config
    from garage_exp.core import config_nodes, schema
    from garage_exp.openscenario.checks import ExportConf
    from garage_exp.slots.schema import SlotDetectorConf, SlotLinesConf
    from garage_exp.results.late import EgoConf
    from garage_exp.scene.schema import BevSpec, CameraRigConf
    from garage_exp.search.schema import SearchConf

    for module in (schema, config_nodes):
        tree = ast.parse(Path(module.__file__).read_text())
        assert not [n.name for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and n.name.endswith("Conf")]
        strings = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
        assert not [s for s in strings if "garage_exp." in s and not s.startswith("garage_exp.core")]
    owners = {key: node.schema.__module__ for key, node in config_nodes.NODES.items()}
    assert not [key for key, module in owners.items() if module.startswith("garage_exp.core")]
    assert owners["search"] == "garage_exp.search.schema" and owners["ego"] == "garage_exp.results.late"
    types = {f.name: f.type for f in dataclasses.fields(config.Config)}
    assert (types["search"], types["ego"], types["slot_detector"], types["export"], types["camera"]) == (
        SearchConf, EgoConf, SlotDetectorConf, ExportConf, CameraRigConf)
    assert schema.Config is config.Config and schema.SlotLinesConf is SlotLinesConf  # code written before the move
    assert schema.BevSpec is BevSpec and not hasattr(schema, "BevConf")  # one class for the node and the spec
    built = OmegaConf.structured(config.Config)
    assert list(built)[:8] == ["plan", "garage", "light", "camera", "palette", "occluder", "case", "ego"]
    assert list(built) == [*config.ORDER]
    assert built.search.objective == "difficulty" and built.slot_detector.lines.max_gap == 0.8


def test_a_new_node_is_one_module_and_its_registration(tmp_path, monkeypatch):
    """A new factor's node: its dataclass and `register_node` in a module of its own (here a temporary one); the
    assembled Config holds it after the placed keys, and the schema check refuses a typo in it."""
    import importlib
    import sys

    from garage_exp import config
    from garage_exp.core import config_nodes, schema
    from garage_exp.core.schema_check import check_schema
    from omegaconf.errors import ConfigKeyError

    (tmp_path / "my_factor.py").write_text(
        "from dataclasses import dataclass\n"
        "from garage_exp.core.config_nodes import register_node\n\n\n"
        "@dataclass\nclass HazeConf:\n    density: float = 0.0\n\n\n"
        "register_node('haze', HazeConf)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assembled = schema.config_schema()
    try:
        haze = importlib.import_module("my_factor").HazeConf
        built = OmegaConf.structured(schema.register_config(schema.assemble(config.ORDER, config.JobValues,
                                                                           config.__name__)))
        assert list(built)[-1] == "haze" and built.haze.density == 0.0 and OmegaConf.get_type(built.haze) is haze
        with pytest.raises(ConfigKeyError):  # a typo fails at composition, as in every node of the schema
            OmegaConf.merge(built, {"haze": {"densty": 1.0}})
        forced = OmegaConf.create({**OmegaConf.to_container(built), "haze": {"densty": 1.0}})  # as `+haze.densty`
        with pytest.raises(GarageError, match=r"haze has no key 'densty' \(did you mean 'density'\?\)"):
            check_schema(forced, [])
    finally:
        del config_nodes.NODES["haze"]
        sys.modules.pop("my_factor", None)
        schema.register_config(assembled)  # the experiment's own Config again, as every other test knows it
