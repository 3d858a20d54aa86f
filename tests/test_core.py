"""The core's shape: import layers, the renderer chosen by config, every shipped experiment and case checked."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.core.paths import PROJECT_ROOT

CONF = PROJECT_ROOT / "conf"


def test_import_layers_hold():
    """`lint-imports` (pyproject.toml: layers, no cycles, no SAPIEN in plain data) passes on the source."""
    exe = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    r = subprocess.run([exe, "--no-cache"], cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "0 broken" in r.stdout


def test_app_holds_only_the_entry_point_and_the_command_line():
    source = (PROJECT_ROOT / "garage_exp" / "cli" / "app.py").read_text()
    assert len(source.splitlines()) < 150
    assert "def run_job" not in source and "def preflight" not in source and "def input_error" not in source


def test_a_second_renderer_is_one_module_named_by_target(tmp_path, monkeypatch):
    from garage_exp.render import Frame, check_renderer, open_renderer

    (tmp_path / "my_backend.py").write_text(
        "class Flat:\n"
        "    def __init__(self, conf):\n"
        "        self.conf = conf\n"
        "def make(**settings):\n"
        "    return Flat(settings)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("GARAGE_EXP_MODIFIER_MODULES", "my_backend")
    conf = OmegaConf.create({"name": "flat", "_target_": "my_backend.make", "max_lights": 4, "shadows": False,
                             "save_frames": "none"})
    check_renderer(conf)
    renderer = open_renderer(conf)
    assert type(renderer).__name__ == "Flat" and renderer.conf["max_lights"] == 4
    assert Frame.__module__ == "garage_exp.render.base"


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

    (cfg,) = _sweep_jobs([f"case={name}", "plan=research"])
    assert str(cfg.case.name) == name
    preflight(cfg, check_space=False)
