"""The job's typed spec and summary (issue 41, item 2): the preflight hands the stages below the job a frozen spec
with no config node in it, the summary is a typed record whose flat mapping is the metrics the job always logged,
and a job opens its detector once."""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Mapping

import numpy as np
import pytest
from conftest import compose_cfg, require, run_app

from garage_exp.results.summary import JobSummary

METRICS = {"confidence_mean": 0.4, "confidence_min": 0.1, "recall": 0.5, "frames_under_threshold": 3.0,
           "visible_fraction_mean": 0.7, "false_positives": 0.0, "frames": 6.0, "difficulty": 0.6,
           "confidence_mean_low": 0.3, "confidence_mean_high": 0.5, "replicates": 2.0, "label.black": 0.4,
           "model.yolov8n": 0.4, "camera.rear": 0.2, "fair_frames": 4.0, "fair_confidence": 0.45,
           "fair_difficulty": 0.55, "fair_recall": 0.5, "late": 1.0, "lateness": 1.0, "late_trajectories": 1.0,
           "late_testable": 1.0, "detection_distance": math.nan, "ttc_at_detection": math.nan,
           "stopping_distance": 4.2, "critical_distance": 6.7, "slot_recall": 0.8, "slot_truth_fair": 3.0}


def test_the_summary_record_gives_back_the_logged_metrics_key_for_key_and_in_order():
    summary = JobSummary.of(METRICS)
    flat = summary.as_dict()
    assert list(flat) == list(METRICS)
    assert all(flat[k] == v or (math.isnan(v) and math.isnan(flat[k])) for k, v in METRICS.items())
    assert summary.fair_difficulty == 0.55 and summary.breakdown["label.black"] == 0.4
    assert summary.metric("slot_recall") == 0.8 and summary.metric("late") == 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        summary.difficulty = 0.0  # type: ignore[misc]
    # a part the job did not measure is left out, not logged as NaN; a trial's run and dir are no metrics
    static = {k: v for k, v in METRICS.items() if not k.startswith(("late", "detection", "ttc", "stopping",
                                                                    "critical", "slot_"))}
    trial = JobSummary.of(static).with_(run_id="r1", output_dir="/x")
    assert trial.late_testable is None and trial.as_dict(trial=False) == static
    assert trial.as_dict()["run_id"] == "r1"
    assert JobSummary().as_dict() == {"difficulty": pytest.approx(math.nan, nan_ok=True)}  # a dry run


_ATOMS = frozenset({str, bytes, int, float, bool, type(None)})


def _config_nodes(value, path="spec", depth: int = 8, seen: dict | None = None) -> list[str]:
    """Where a config node (DictConfig, ListConfig) sits inside `value`: itself, or inside its dicts, lists, tuples,
    sets and dataclasses, `depth` levels down (deep enough for a spec's records; a bound, as a job's shots and
    poses nest without end). `seen` ((id, depth) -> (instance, answer)) answers a dataclass instance walked
    before at once (the watch meets a job's site or camera thousands of times)."""
    from omegaconf import Container

    if type(value) in _ATOMS:
        return []
    if isinstance(value, Container):
        return [path]
    if depth == 0 or isinstance(value, (str, bytes, int, float, np.ndarray, np.generic)):
        return []
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        if seen is not None and (id(value), depth) in seen:
            return [path + p for p in seen[id(value), depth][1]]
        found = [p for f in dataclasses.fields(value)
                 for p in _config_nodes(getattr(value, f.name, None), f"{path}.{f.name}", depth - 1, seen)]
        if seen is not None:  # the instance kept: its id stays its own
            seen[id(value), depth] = (value, [p[len(path):] for p in found])
        return found
    if isinstance(value, Mapping):
        return [p for k, v in value.items() for p in _config_nodes(v, f"{path}[{k!r}]", depth - 1, seen)]
    if isinstance(value, (list, tuple, set, frozenset)):
        return [p for k, v in enumerate(value) for p in _config_nodes(v, f"{path}[{k}]", depth - 1, seen)]
    return []


def test_the_preflight_hands_a_frozen_typed_spec_without_a_config_node():
    require("assets")
    from garage_exp.perception.detect.matching import Scoring
    from garage_exp.results.late import EgoConf
    from garage_exp.results.table import FairRule
    from garage_exp.run.preflight import preflight
    from garage_exp.run.spec import JobSpec

    cfg = compose_cfg("plan=tiny", "search.min_visible=0.3", "detector.threshold=0.4", "ego.speed=7",
                      "renderer.save_frames=none", "dataset=true")
    prepared = preflight(cfg, check_space=False, load=False)
    spec = prepared.spec
    assert isinstance(spec, JobSpec) and _config_nodes(spec) == []
    assert "config" not in {f.name for f in dataclasses.fields(JobSpec)}  # typed parts only (issue 48 item 2)
    assert spec.frames.look == str(cfg.look.name) and spec.frames.dataset and spec.frames.seed == int(cfg.seed)
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.seed = 1  # type: ignore[misc]
    assert spec.fair == FairRule(0.3, 25.0, 0.5) and spec.scoring == Scoring(0.4, float(cfg.detector.iou),
                                                                              str(cfg.detector.match))
    assert isinstance(spec.ego, EgoConf) and spec.ego.speed == 7.0
    assert spec.detector is prepared.detector and spec.sensor["_target_"] == cfg.sensor._target_
    assert (spec.outputs.save_frames, spec.outputs.dataset, spec.outputs.lean) == ("none", True, False)
    assert spec.primary == "front" and spec.names.case == str(cfg.case.name)


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_a_job_opens_its_detector_once(tmp_path, mlflow_uri, monkeypatch):
    """The preflight opens the detector (its models loaded and checked in the detector's process) and the frames
    run on that one; before, the frames opened it a second time."""
    from garage_exp.perception.detect import worker

    opened = []
    real = worker.open_detector
    monkeypatch.setattr(worker, "open_detector", lambda *a, **k: opened.append(a[0]) or real(*a, **k))
    r = run_app(["plan=tiny", "case.motion.start=4.0", "case.motion.end=4.0", "renderer.save_frames=none",
                 "camera.width=160", "camera.height=120", "detector.models=[yolov8n_int8_openvino_model]",
                 f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert len(opened) == 1, opened


BELOW_RUN = ("plan", "scene", "scenario", "render", "perception", "results", "tracking", "slots", "exports",
             "openscenario")


@contextlib.contextmanager
def config_nodes_handed_below_run():
    """Every call into a layer below the job (BELOW_RUN) whose arguments hold a config node, as
    (module, function, argument, caller) - watched with a profile hook on this thread and the threads it starts."""
    import sys
    import threading
    from pathlib import Path

    import garage_exp

    root = str(Path(garage_exp.__file__).parent) + "/"
    handed: list[tuple[str, str, str, str]] = []
    seen: dict = {}

    def watch(frame, event, arg):
        if event != "call" or not frame.f_code.co_filename.startswith(root):
            return
        module = frame.f_code.co_filename[len(root):]
        if module.split("/")[0] not in BELOW_RUN:
            return
        code = frame.f_code
        for name in code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]:
            # the argument, or inside it three levels down (a plan's cells, a scene's entities: deeper costs minutes)
            for where in _config_nodes(frame.f_locals.get(name), name, 3, seen):
                caller = frame.f_back.f_code
                called_by = f"{caller.co_filename.removeprefix(root)}:{caller.co_name}"
                handed.append((module, code.co_name, where, called_by))

    sys.setprofile(watch)
    threading.setprofile(watch)
    try:
        yield handed
    finally:
        sys.setprofile(None)
        threading.setprofile(None)


@dataclasses.dataclass
class _Holder:
    part: object


def test_the_watch_sees_a_config_node_handed_below_run():
    """The watch below can fail: a node handed to a scene check is seen, as an argument or inside a dict, a list
    or a dataclass handed as one (the check then fails on what it was handed: the watch saw the call first)."""
    from omegaconf import OmegaConf

    from garage_exp.scene.structure import check_garage

    cfg = compose_cfg("plan=tiny")
    plain = OmegaConf.to_container(cfg.garage, resolve=True)  # the same values as plain data: not a node
    hidden = [{"a": cfg.garage}, [1, cfg.garage], _Holder({"b": (cfg.garage,)}), _Holder([plain])]
    with config_nodes_handed_below_run() as handed:
        check_garage(cfg.garage)
        for value in hidden:
            with contextlib.suppress(Exception):
                check_garage(value)
    assert [(m, f, a) for m, f, a, _ in handed] == [("scene/structure.py", "check_garage", a) for a in (
        "garage", "garage['a']", "garage[1]", "garage.part['b'][0]")]


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_no_stage_below_the_job_is_handed_a_config_node(tmp_path, mlflow_uri):
    """A job that reaches most stages (replicates, random materials, worn paint, an OpenSCENARIO export, a
    dataset) and an adversary's episode hand the layers below `run` plain data only: Settings, the spec's
    records, never a DictConfig (issue 41 item 2)."""
    from garage_exp.gym.env import StepOutEnv

    with config_nodes_handed_below_run() as handed:
        r = run_app(["plan=tiny", "case.motion.start=4.0", "case.motion.end=3.5", "replicates=2",
                     "materials=random", "wear=worn", "export.openscenario=true", "dataset=true",
                     "renderer.save_frames=none", "camera.width=160", "camera.height=120",
                     "detector.models=[yolov8n_int8_openvino_model]", f"tracking.uri={mlflow_uri}"], tmp_path)
        assert r.returncode == 0, r.stderr[-3000:]
        env = StepOutEnv(overrides=["camera.width=160", "camera.height=120",
                                    "detector.models=[yolov8n_int8_openvino_model]"])
        env.reset(seed=0)
        env.step(env.action_space.sample())
        env.close()
    assert not handed, "\n".join(map(str, sorted(set(handed))))


def test_the_scene_builder_is_handed_each_group_as_its_schemas_dataclass(monkeypatch):
    """Issue 48 item 2: the scene builder's parts are the typed dataclasses that own them, converted once by the
    preflight, not attribute dicts: a misspelt key is an AttributeError (a dict's `get` was a silent None), and
    nested groups (the case's motion, its actors, the rig's cameras) are typed too."""
    require("assets")
    from garage_exp.run import spec as spec_mod
    from garage_exp.run.preflight import preflight
    from garage_exp.scenario.schema import ActorConf, CaseConf, MotionConf
    from garage_exp.scene.schema import CameraConf, CameraRigConf, GarageConf, LightConf, MaterialsConf

    built = []
    monkeypatch.setattr(spec_mod, "scene_spec", lambda cfg, made=spec_mod.scene_spec: built.append(1) or made(cfg))
    prepared = preflight(compose_cfg("plan=small", "case=stepout", "ego.speed=7", "light.temperature=3000"),
                         check_space=False, load=False)
    scene = prepared.spec.scene
    assert len(built) == 1  # the preflight checks the groups it hands the builder: one conversion, not two
    parts = (scene.garage, scene.light, scene.camera, scene.case, scene.materials)
    assert [type(p) for p in parts] == [GarageConf, LightConf, CameraRigConf, CaseConf, MaterialsConf]
    assert isinstance(scene.case.motion, MotionConf) and isinstance(scene.camera.cameras[0], CameraConf)
    assert all(isinstance(a, ActorConf) for a in scene.case.actors.values())
    assert scene.light.temperature == 3000.0 and scene.ego_speed == 7.0
    assert not hasattr(scene, "get") and not hasattr(scene.garage, "get")
    with pytest.raises(AttributeError):
        scene.garage.ceiling_heigth  # noqa: B018 - the misspelling is the test


def test_a_job_converts_its_config_once(tmp_path, mlflow_uri, monkeypatch):
    """The job's levels are named (run.job.name_levels) before the preflight converts the config, so the whole
    config becomes plain data once and the spec says the names the run logs; before, the job converted it a
    second time after renaming it."""
    require("assets")
    from garage_exp.core.plain import Settings

    converted = []

    def counting(self, *args, **kwargs):
        dict.__init__(self, *args, **kwargs)
        if {"plan", "case", "seed", "renderer"} <= self.keys():  # the whole config, not one of its groups
            converted.append(self.case.name)

    monkeypatch.setattr(Settings, "__init__", counting)
    r = run_app(["plan=tiny", "dry_run=true", "camera=front", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert len(converted) == 1, converted


def test_a_configs_plain_values_are_to_containers():
    """core.plain.resolved reads a config's values from its nodes (a job and each checked draw convert ~630 of them):
    equal to OmegaConf.to_container(resolve=True) (and resolve=False, the schema check's) on the shipped configs, the wide space's included, and on
    interpolations to values, nodes and lists, missing values, None nodes and enums; what to_container refuses it
    refuses in the same words."""
    import enum

    from omegaconf import OmegaConf

    from garage_exp.core.plain import resolved

    for overrides in [(), ("space=wide", "plan=generated", "case=oneshot"), ("case=3", "sensor=noisy")]:
        cfg = compose_cfg(*overrides)
        assert resolved(cfg) == OmegaConf.to_container(cfg, resolve=True), overrides
        assert resolved(cfg, resolve=False) == OmegaConf.to_container(cfg, resolve=False), overrides

    class Kind(enum.Enum):
        A = 1

    made = OmegaConf.create({"a": 1, "b": "${a}", "c": {"d": [1, "${a}", {"e": "${c.f}"}], "f": "x${a}y"},
                             "g": "${c}", "h": "${c.d}", "i": "???", "j": None, "k": {"l": "???"}, "m": Kind.A,
                             "n": "\\${a}", "o": "${oc.select:c.f,zz}", "p": [], "q": {}})
    made.k = "???"
    made.j = None
    ours, theirs = resolved(made), OmegaConf.to_container(made, resolve=True)
    assert ours == theirs and type(ours["m"]) is Kind and ours["g"] is not ours["c"]
    made.r = "${c}"  # a node that is an interpolation, kept as written unresolved
    assert resolved(made, resolve=False) == OmegaConf.to_container(made, resolve=False)
    assert resolved(made, resolve=False)["b"] == "${a}"
    broken = OmegaConf.create({"a": "${nowhere}", "b": {"c": "${a}"}})
    with pytest.raises(Exception) as ours_raised:
        resolved(broken)
    with pytest.raises(Exception) as theirs_raised:
        OmegaConf.to_container(broken, resolve=True)
    assert (type(ours_raised.value), str(ours_raised.value)) == (type(theirs_raised.value), str(theirs_raised.value))


def test_holds_answers_as_in_does_without_an_exception_for_a_missing_key():
    """core.plain.holds is `key in node`: for keys held, missing, mandatory-missing ('???'), None, interpolations
    and a None node, on plain and struct nodes. For a key its node does not hold it answers without
    OmegaConf raising (and formatting) a ConfigAttributeError: `settings` asks it of every group of every draw."""
    import omegaconf._utils
    from omegaconf import DictConfig, OmegaConf

    from garage_exp.core.plain import holds

    made = OmegaConf.create({"a": 1, "b": "???", "c": None, "d": "${a}", "e": "${nowhere}", "f": {"g": 1},
                             "h": DictConfig(None)})
    for struct in (False, True):
        OmegaConf.set_struct(made, struct)
        for node in (made, made.f):
            for key in "abcdefghz":
                assert holds(node, key) == (key in node), (struct, key)
    raised = []
    real = omegaconf._utils.format_and_raise

    def counting(*args, **kwargs):
        raised.append(args)
        return real(*args, **kwargs)

    cfg = compose_cfg("space=wide")
    with pytest.MonkeyPatch.context() as patch:
        for module in ("omegaconf._utils", "omegaconf.base", "omegaconf.basecontainer", "omegaconf.dictconfig"):
            patch.setattr(f"{module}.format_and_raise", counting, raising=False)
        groups = [cfg._get_node(k) for k in cfg if isinstance(cfg._get_node(k), DictConfig)]
        assert len(groups) > 10 and not any(holds(group, "hydra") for group in groups)
    assert raised == []
