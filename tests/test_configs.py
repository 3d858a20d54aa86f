"""Every level of every config group, every experiment and every case composes, and a plan-only job
(dry_run=true) runs with each. Fast: compose in-process, dry runs in this process one after another, each a run in
one MLflow store."""

from __future__ import annotations


import pytest
import yaml
import conftest
from conftest import ROOT, run_app
from omegaconf import OmegaConf


CONF = ROOT / "conf"
GROUPS = sorted(p.name for p in CONF.iterdir() if p.is_dir() and p.name not in ("hydra", "experiment"))
LEVELS = [(g, p.stem) for g in GROUPS for p in sorted((CONF / g).glob("*.yaml"))]
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
# Arrangements whose parked cars or vans fit no bay of the tiny plan (1.7 m wide): a job refuses them there, and so
# does its dry run, which builds the scene too.
WIDE_BAYS = ("occluder=pillar_cars", "occluder=vans")


def compose_cfg(*overrides: str):
    return conftest.compose_cfg(*overrides, hydra=True)


def test_every_group_has_levels_and_cases_and_experiments_exist():
    assert len(LEVELS) >= 2 * len(GROUPS) - 4  # garage, renderer, tracking have one level; the rest several
    assert {"1", "2", "3"} <= {lv for g, lv in LEVELS if g == "case"}
    assert EXPERIMENTS == ["case3_table", "cpnco", "cpra", "light_sensor", "light_table"]


@pytest.mark.parametrize("group,level", LEVELS, ids=[f"{g}={lv}" for g, lv in LEVELS])
def test_level_composes_with_its_file_values(group, level):
    """The composed config holds every value the level's file sets (under modifiers.<group> for the extra
    factors packaged there; the schema may add defaults beside them)."""
    cfg = compose_cfg(f"{group}={level}")
    text = (CONF / group / f"{level}.yaml").read_text()
    data = {k: v for k, v in (yaml.safe_load(text) or {}).items() if k != "defaults"}
    package = level_package(group, level)
    node = OmegaConf.to_container(cfg if package == "_global_" else OmegaConf.select(cfg, package), resolve=False)
    assert data, f"{group}/{level}.yaml sets nothing"
    missing = [key for key, value in data.items() if not holds(node.get(key), value)]
    assert not missing, (group, level, missing)


def holds(composed, written) -> bool:
    """The composed value holds what the file wrote: dicts key by key (the schema adds defaults), scalars
    equal or equal as text (the schema types a YAML 1 as a str key "1" where it says str)."""
    if isinstance(written, dict):
        return isinstance(composed, dict) and all(holds(composed.get(k), v) for k, v in written.items())
    if isinstance(written, list):
        return isinstance(composed, list) and len(composed) == len(written) and all(
            holds(c, w) for c, w in zip(composed, written))
    return composed == written or str(composed) == str(written)


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_composes_its_sweep(experiment):
    cfg = compose_cfg(f"+experiment={experiment}")
    spec = yaml.safe_load((CONF / "experiment" / f"{experiment}.yaml").read_text())
    assert dict(cfg.hydra.sweeper.params) == spec["hydra"]["sweeper"]["params"]
    assert cfg.tracking.experiment == spec["tracking"]["experiment"]
    override = next(d for d in spec["defaults"] if isinstance(d, dict))
    assert str(cfg.case.name) == str(next(iter(override.values())))


def test_dry_run_with_every_level_and_experiment(tmp_path_factory):
    """A plan-only job (dry_run=true) with each level of each group and with each +experiment= finishes: the
    product's own checks accept it and it writes its config and plan map."""
    jobs = [(f"{g}={lv}", [f"{g}={lv}"] if g in ("plan", "case") or f"{g}={lv}" in WIDE_BAYS
             else ["plan=tiny", f"{g}={lv}"])
            for g, lv in LEVELS]  # the small plan, unless the level needs a feature of the default plan
    # (case=cpra is scored by its rear camera, case.camera: its defaults list brings the rear rig)
    jobs += [(f"experiment={e}", [f"+experiment={e}"]) for e in EXPERIMENTS]
    # one store for all the jobs (each a run in it): a store of its own per job made MLflow open a new database
    # engine, compile its statements and create the experiment each time, a third of a dry run's time
    store = f"tracking.uri=sqlite:///{tmp_path_factory.mktemp('store')}/mlflow.db"
    for name, level_args in jobs:
        work = tmp_path_factory.mktemp(name.replace("=", "-"))
        args = ["dry_run=true", *level_args, store]
        proc = run_app(args, work)  # in this process, one after another
        assert proc.returncode == 0, (name, proc.stderr[-3000:])
        written = OmegaConf.load(work / "run" / "config.yaml")
        group, level = name.split("=")
        if group == "experiment":
            assert written.tracking.experiment == compose_cfg(f"+experiment={level}").tracking.experiment
        else:  # the job ran with the level: its written config holds what the level composes to, at its package
            package = level_package(group, level)
            package = group if package == "_global_" else package  # a preset (look=): its own node suffices
            expected = OmegaConf.to_container(OmegaConf.select(conftest.compose_cfg(*args), package), resolve=True)
            got = OmegaConf.to_container(OmegaConf.select(written, package), resolve=True)
            assert expected and holds(got, expected), (name, package, got, expected)
        assert (work / "run" / "plan_map.png").stat().st_size > 1000, name


def level_package(group: str, level: str) -> str:
    """Where a level's file puts its values: its `# @package` line, else its group."""
    text = (CONF / group / f"{level}.yaml").read_text()
    return text.split("# @package ", 1)[1].split()[0] if "# @package " in text else group
