"""The core's shape: the entry point, the renderer chosen by config, every shipped experiment and case checked.
(The import layers are `lint-imports`, which `make test` runs before pytest.)"""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.core.paths import PROJECT_ROOT

CONF = PROJECT_ROOT / "conf"


def test_app_holds_only_the_entry_point_and_the_command_line():
    source = (PROJECT_ROOT / "garage_exp" / "cli" / "app.py").read_text()
    assert len(source.splitlines()) < 150
    assert "def run_job" not in source and "def preflight" not in source and "def input_error" not in source


FLAT_BACKEND = '''
"""A second backend, written by the test: every camera sees one flat colour and no entity; each call is logged."""
import json
import os

import numpy as np

from garage_exp.render.base import Frame
from garage_exp.scene.camera import camera_to_world, intrinsics_of


GREY = 90


class Flat:
    def __init__(self, settings):
        self.log = open(os.environ["FLAT_LOG"], "a")
        self.log.write(json.dumps({"call": "make", **settings}) + "\\n")

    def load(self, scene):
        self.scene, self.poses = scene, {}
        self.cameras = {c.name: c for c in scene.cameras}
        self._ids = {e.name: k + 1 for k, e in enumerate(scene.actors())}
        self.log.write(json.dumps({"call": "load", "cameras": list(self.cameras)}) + "\\n")

    @property
    def ids(self):
        return self._ids

    def set_pose(self, name, pose):
        self.poses[name] = pose

    def render(self, camera_name):
        spec, ego = self.cameras[camera_name], self.poses["ego"]
        rgb = np.full((spec.height, spec.width, 3), GREY, np.uint8)
        ids = np.zeros((spec.height, spec.width), np.int32)
        self.log.write(json.dumps({"call": "render", "camera": camera_name, "x": ego.x, "y": ego.y}) + "\\n")
        self.log.flush()
        return Frame(camera_name, rgb, ids, camera_to_world(ego, spec), *intrinsics_of(spec))

    def unoccluded_ids(self, camera_name, names):
        return {}


def make(*, name, max_lights, shadows, save_frames, device):
    return Flat({"name": name, "max_lights": max_lights, "shadows": shadows, "save_frames": save_frames,
                 "device": device})
'''


@pytest.mark.detect
def test_a_second_renderer_is_one_module_named_by_target(tmp_path, monkeypatch):
    """A backend is one module with a `make(**settings)` factory, named by `renderer._target_` (allowed through
    $GARAGE_EXP_MODIFIER_MODULES): a real two-frame job renders every shot with it, without SAPIEN, and its
    frame table is made of what it drew (one render call per row, nothing in view)."""
    import csv
    import json

    from conftest import require, run_app

    require("vehicles", "models")
    (tmp_path / "flat_backend.py").write_text(FLAT_BACKEND)
    monkeypatch.syspath_prepend(str(tmp_path))  # the job runs in this process (conftest.run_app)
    log = tmp_path / "calls.jsonl"
    env = {"GARAGE_EXP_MODIFIER_MODULES": "flat_backend", "FLAT_LOG": str(log)}
    r = run_app(["plan=tiny", "case.motion.start=5.0", "case.motion.end=4.0", "case.motion.step=1.0",
                    "palette.target_colours=[black]", "detector.models=[yolov8n_int8_openvino_model]",
                    "renderer._target_=flat_backend.make", "renderer.name=flat", "renderer.max_lights=3",
                    "renderer.save_frames=none", f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"], tmp_path, env)
    assert r.returncode == 0, r.stderr[-3000:]
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    renders = [c for c in calls if c["call"] == "render"]
    assert calls[:2] == [{"call": "make", "name": "flat", "max_lights": 3, "shadows": False, "save_frames": "none",
                          "device": "auto"},
                         {"call": "load", "cameras": ["front"]}]
    assert len(renders) == 2
    with open(tmp_path / "run" / "frames.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [(x["camera"], float(x["ego_x"]), float(x["ego_y"])) for x in rows] == \
        [(c["camera"], pytest.approx(c["x"], abs=1e-3), pytest.approx(c["y"], abs=1e-3)) for c in renders]
    assert [float(x["position"]) for x in rows] == [5.0, 4.0]
    assert {(x["visible_fraction"], x["kitti"]) for x in rows} == {("0.0", "out_of_view")}  # it drew no target
    assert OmegaConf.load(tmp_path / "run" / "config.yaml").renderer._target_ == "flat_backend.make"


def test_renderer_target_outside_the_allowed_modules_is_refused(monkeypatch):
    from garage_exp.render import check_renderer

    monkeypatch.delenv("GARAGE_EXP_MODIFIER_MODULES", raising=False)
    conf = OmegaConf.create({"_target_": "os.system", "max_lights": 8, "save_frames": "key"})
    with pytest.raises(GarageError) as info:
        check_renderer(conf)
    assert info.value.where == "renderer._target_" and "'os.system' is not a renderer" in str(info.value)


def test_sapien_backend_has_every_member_of_the_interface():
    """Checked by name, without a Vulkan device: SapienRenderer offers everything `Renderer` declares."""
    from garage_exp.render.base import Renderer
    from garage_exp.render.sapien_backend import SapienRenderer

    members = {n for n in vars(Renderer) if not n.startswith("_")}
    assert members == {"load", "ids", "set_pose", "render", "unoccluded_ids"}
    assert all(hasattr(SapienRenderer, n) for n in members)


def _sweep_jobs(overrides: list[str]):
    """The composed config of every job a `-m` command would run, via Hydra's own sweeper."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    import garage_exp.cli.app  # noqa: F401  the schema and resolvers
    from garage_exp.cli.app import quote_numeric_choices
    from garage_exp.cli.callbacks import sweep_jobs

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        config = compose("config", overrides=quote_numeric_choices(overrides), return_hydra_config=True)
        loader = GlobalHydra.instance().config_loader()
        return [loader.load_sweep_config(config, job) for job in sweep_jobs(config)]


@pytest.mark.parametrize("name", sorted(p.stem for p in (CONF / "experiment").glob("*.yaml")))
def test_every_shipped_experiment_composes_and_passes_preflight(name):
    """Each job of the sweep: config values, plan, weights, assets and the whole scene description (a dry run
    of everything but rendering and detection)."""
    from garage_exp.run.preflight import preflight

    jobs = _sweep_jobs([f"+experiment={name}", "plan=research"])
    assert len(jobs) >= 2
    for cfg in jobs:
        prepared = preflight(cfg, check_space=False)
        assert prepared.plan_path.is_file() and prepared.classified.plan.name == "research"
        assert prepared.scene is not None and prepared.setup.shots, "a real job's preflight builds its scene"


@pytest.mark.parametrize("name", sorted(p.stem for p in (CONF / "case").glob("*.yaml")))
def test_every_shipped_case_composes_and_passes_preflight(name):
    from garage_exp.run.preflight import preflight

    rig = {"cpra": ["camera=rear"]}.get(name, [])  # scored by its rear camera (case.camera): a front rig is refused
    (cfg,) = _sweep_jobs([f"case={name}", "plan=research", *rig])
    assert str(cfg.case.name) == name
    preflight(cfg, check_space=False)
