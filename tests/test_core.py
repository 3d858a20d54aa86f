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


def test_every_hydra_command_runs_in_the_one_shell():
    """Issue 32, item 1: each Hydra command is a thin task plus a `shell.Command`; none registers resolvers or
    schemas, installs signal handlers or turns errors into exit codes itself."""
    import importlib

    from garage_exp.core import shell

    for package, config in (("cli", "config"), ("gym", "gym"), ("train", "train"), ("loop", "loop"),
                            ("verify", "verify")):
        app = importlib.import_module(f"garage_exp.{package}.app")
        assert isinstance(app.COMMAND, shell.Command) and app.COMMAND.config_name == config
        source = (PROJECT_ROOT / "garage_exp" / package / "app.py").read_text()
        for own in ("register_new_resolver", "signal.signal", "hydra.main", "EXIT_INPUT", "install_error_report",
                    "def remove_untouched", "sys.exit"):
            assert own not in source, (package, own)


def test_the_console_scripts_are_the_commands():
    """pyproject's [project.scripts] name importable functions: the five Hydra commands' `cli` and the argparse
    commands' `main`, each also `python -m garage_exp[.PACKAGE]`."""
    import importlib
    import tomllib

    scripts = tomllib.loads((PROJECT_ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert {"garage-exp", "garage-exp-gym", "garage-exp-train", "garage-exp-loop", "garage-exp-verify",
            "garage-exp-plan", "garage-exp-report", "garage-exp-exports", "garage-exp-assets"} <= set(scripts)
    for name, target in scripts.items():
        module, _, function = target.partition(":")
        assert callable(getattr(importlib.import_module(module), function)), name
        if module.endswith(".app"):  # the package's `python -m` runs the same function (garage_exp's: cli's)
            package = module.removesuffix(".app").removesuffix(".cli")
            main = PROJECT_ROOT / package.replace(".", "/") / "__main__.py"
            assert f"from {module} import {function}" in main.read_text(), name


def test_a_console_script_runs_a_command(tmp_path, capsys):
    """The entry functions take argv as a console script passes it: `garage-exp-plan check FILE`, and a Hydra
    command's bad input is its one line and exit 2 (its name first), nothing left of the run dir."""
    from conftest import run_in_process

    from garage_exp.plan.__main__ import main as plan_main
    from garage_exp.train.app import cli as train_cli

    assert plan_main(["check", str(PROJECT_ROOT / "plans" / "tiny.yaml")]) == 0
    assert "plan tiny" in capsys.readouterr().out
    r = run_in_process([], tmp_path, entry=lambda: train_cli(["epochs=0", f"hydra.run.dir={tmp_path / 'run'}"]))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["garage_exp.train: epochs: 0 is outside 1-10000"]
    assert not (tmp_path / "run").exists()


def test_a_refused_command_removes_only_the_folders_hydra_made(tmp_path, monkeypatch):
    """One clean-up for every command: the run dir while it holds only Hydra's files, then each folder above it left
    empty - the date levels under outputs/ (never outputs/ itself), a loop's own `dir` - up to the working directory
    (gym's rule removed one level anywhere, train's only under outputs/, the loop a third way)."""
    from garage_exp.core import shell

    def hydra_dir(path):
        (path / ".hydra").mkdir(parents=True)
        (path / "app.log").write_text("")
        return path

    outputs = tmp_path / "outputs"
    monkeypatch.setattr(shell, "OUTPUTS_DIR", outputs)
    monkeypatch.chdir(tmp_path)
    (outputs / "train" / "2026-01-01" / "09-00-00").mkdir(parents=True)  # an earlier run of the same day
    shell.remove_untouched(hydra_dir(outputs / "train" / "2026-01-01" / "10-00-00"))
    assert sorted(p.name for p in (outputs / "train" / "2026-01-01").iterdir()) == ["09-00-00"]
    shell.remove_untouched(hydra_dir(outputs / "gym" / "2026-01-02" / "10-00-00"))
    assert not (outputs / "gym").exists() and outputs.is_dir()
    shell.remove_untouched(hydra_dir(tmp_path / "mine" / "loop" / "hydra"))  # a loop's dir=mine/loop
    assert not (tmp_path / "mine").exists() and tmp_path.is_dir()
    used = hydra_dir(tmp_path / "b" / "run")
    (used / "frames.csv").write_text("")
    shell.remove_untouched(used)
    assert (used / "frames.csv").is_file()


def test_a_stop_is_forgotten_when_the_command_ends(monkeypatch):
    """SIGINT/SIGTERM make MLflow give up fast (its time-outs in the environment); the next command in the same
    process (a test session, a benchmark) gets the user's settings back."""
    from garage_exp.core.state import STATE

    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_TIMEOUT", "120")
    monkeypatch.delenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", raising=False)
    STATE.begin().stop()
    import os

    assert STATE.stopping and os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] == "3"
    STATE.end()
    assert not STATE.stopping and os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] == "120"
    assert "MLFLOW_HTTP_REQUEST_MAX_RETRIES" not in os.environ


def test_a_stop_quiets_the_stores_connection_pool_until_the_command_ends(caplog):
    """Ctrl-C inside an SQLite fetch: SQLAlchemy closes the connection and logged 'Error closing cursor' with a
    traceback under the command's one line (a flaky test_ctrl_c_exits_130 under load). From the stop to the
    command's end the pool logs nothing; after it, as before."""
    import logging

    from garage_exp.core.state import STATE

    pool = logging.getLogger("sqlalchemy.pool.impl.QueuePool")  # the logger SQLAlchemy's message came from
    STATE.begin().stop()
    pool.error("Error closing cursor")
    assert "Error closing cursor" not in caplog.text
    STATE.end()
    pool.error("after the command")
    assert "after the command" in caplog.text and logging.getLogger("sqlalchemy.pool").level == logging.NOTSET


FLAT_BACKEND = '''
"""A second backend, written by the test: every camera sees one flat colour and no entity; each call is logged."""
import json
import os

import numpy as np

from garage_exp.render.base import Frame
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.lenses import lens_of


GREY = 90


class Flat:
    description = None  # the render scene loads a scene this does not hold

    def __init__(self, settings):
        self.log = open(os.environ["FLAT_LOG"], "a")
        self.log.write(json.dumps({"call": "make", **settings}) + "\\n")

    def load(self, scene):
        self.scene, self.description, self.poses = scene, scene, {}
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
        return Frame(camera_name, rgb, ids, camera_to_world(ego, spec), lens_of(spec))

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
    from garage_exp.render.open import check_renderer

    monkeypatch.delenv("GARAGE_EXP_MODIFIER_MODULES", raising=False)
    conf = OmegaConf.create({"_target_": "os.system", "max_lights": 8, "save_frames": "key"})
    with pytest.raises(GarageError) as info:
        check_renderer(conf)
    assert info.value.where == "renderer._target_" and "'os.system' is not a renderer" in str(info.value)


def test_sapien_backend_has_every_member_of_the_interface():
    """Checked by name, without a Vulkan device: SapienRenderer offers everything `Renderer` declares (what the
    render scene, render/batch.py, reads of a sub-scene)."""
    from garage_exp.render.base import Renderer
    from garage_exp.render.sapien_backend import SapienRenderer

    members = {n for n in vars(Renderer) if not n.startswith("_")} | set(Renderer.__annotations__)
    assert members == {"description", "load", "ids", "set_pose", "render", "unoccluded_ids", "restyle", "sibling"}
    renderer = SapienRenderer()  # no scene loaded: nothing of SAPIEN's is made
    assert all(hasattr(renderer, n) for n in members)


def _sweep_jobs(overrides: list[str]):
    """The composed config of every job a `-m` command would run, via Hydra's own sweeper."""
    from conftest import compose_cfg, hydra_loader

    from garage_exp.cli.callbacks import sweep_jobs

    with hydra_loader() as loader:
        config = compose_cfg(*overrides, hydra=True)
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

    from conftest import compose_cfg

    # A single run's config, composed once (not a one-job sweep: that composed it twice); cpra brings the rear rig
    # it is scored by.
    cfg = compose_cfg(f"case={name}", "plan=research")
    assert str(cfg.case.name) == name
    preflight(cfg, check_space=False)
