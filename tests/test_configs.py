"""Every level of every config group, every experiment and every case composes, and a plan-only job
(dry_run=true) runs with each. Fast: compose in-process, dry runs in this process one after another, each a run in
one MLflow store."""

from __future__ import annotations


import re

import pytest
import yaml
from conftest import ROOT, run_app
from omegaconf import OmegaConf


CONF = ROOT / "conf"
GROUPS = sorted(p.name for p in CONF.iterdir() if p.is_dir() and p.name not in ("hydra", "experiment"))
LEVELS = [(g, p.stem) for g in GROUPS for p in sorted((CONF / g).glob("*.yaml"))]
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
# Arrangements whose parked cars or vans fit no bay of the tiny plan (1.7 m wide): a job refuses them there, and so
# does its dry run, which builds the scene too.
WIDE_BAYS = ("occluder=pillar_cars", "occluder=vans")


# Levels whose job sets other groups' values: plan=generated hands its draw's garage on (garage.*, the pillar size).
HANDS_ON = {("plan", "generated"): {"garage", "pillar"}}


def overridden(group: str, level: str) -> set[str]:
    """The groups a level's (or an experiment's) defaults list overrides (look=flat sets materials, clutter, sensor;
    case=cpra the camera), or its job sets (HANDS_ON): a dry run holding such a level holds no level of those
    groups, which would undo its choice - but the case an experiment names, given as that case's own level."""
    text = (CONF / group / f"{level}.yaml").read_text()
    return set(re.findall(r"override /(\w+)", text)) | HANDS_ON.get((group, level), set())


def experiment_case(experiment: str) -> str:
    return re.search(r"override /case: \"?(\w+)", (CONF / "experiment" / f"{experiment}.yaml").read_text())[1]


def dry_run_jobs() -> list[dict[str, str]]:
    """Every level of every group and every experiment in as few plan-only jobs as they allow (a dry run is mostly
    Hydra composing the config twice, whatever the number of overrides: 18 jobs instead of 66). A job holds at most
    one level of a group and none whose choice another of its levels overrides. Each plan other than the default
    one is a job's plan; each case, each level that needs a feature of the default plan (WIDE_BAYS) and each
    experiment runs on the default plan, as they would alone; an experiment (`+experiment`) joins the job of the
    case it names."""
    default_plan = "research"
    jobs = [{"plan": lv} for g, lv in LEVELS if g == "plan" and lv != default_plan]
    jobs += [{"plan": default_plan, "case": lv} for g, lv in LEVELS if g == "case"]
    for group, level in LEVELS:
        if group in ("plan", "case"):
            continue
        wide = f"{group}={level}" in WIDE_BAYS
        job = next((j for j in jobs
                    if group not in j and (not wide or j["plan"] == default_plan)
                    and not overridden(group, level) & set(j)
                    and not any(group in overridden(g, lv) for g, lv in j.items())), None)
        if job is None:
            jobs.append(job := {"plan": default_plan})
        job[group] = level
    for experiment in EXPERIMENTS:
        case = experiment_case(experiment)
        job = next((j for j in jobs if j.get("case") == case and "+experiment" not in j
                    and not (overridden("experiment", experiment) - {"case"}) & set(j)), None)
        if job is None:
            jobs.append(job := {"plan": default_plan, "case": case})
        job["+experiment"] = experiment
    return jobs


@pytest.fixture(scope="module")
def dry_runs(tmp_path_factory) -> dict:
    """The plan-only jobs (dry_run=true) holding every level and every +experiment= between them, run through
    the command line in this process one after another, each a run in one MLflow store (a store of its own per
    job made MLflow open a new database engine, compile its statements and create the experiment each time, a
    third of a dry run's time). For each job's overrides: (its arguments, the config the job was given - as Hydra
    composed it, before the job touched it, see ran_with -, the completed command, its run dir)."""
    store = f"tracking.uri=sqlite:///{tmp_path_factory.mktemp('store')}/mlflow.db"
    jobs = [[f"{g}={lv}" for g, lv in job.items()] for job in dry_run_jobs()]
    done = {}
    with pytest.MonkeyPatch.context() as patch:
        given = ran_with(patch)
        for k, overrides in enumerate(jobs):
            work = tmp_path_factory.mktemp(f"job{k}")
            args = ["dry_run=true", *overrides, store]
            given.clear()
            proc = run_app(args, work)
            done[tuple(overrides)] = (args, given[0] if given else None, proc, work / "run")
    return done


def ran_with(patch) -> list:
    """The config each job is given (the job's first step, its preflight, sees it as Hydra composed it from the
    command line), kept as (the config, its hydra node, the config resolved in the job): what the composition tests
    check, without composing each job's config a second time."""
    import copy

    from hydra.core.hydra_config import HydraConfig

    from garage_exp.run import job

    given, preflight = [], job.preflight

    def seen(cfg, *args, **kwargs):
        given.append(Given((copy.deepcopy(cfg), copy.deepcopy(HydraConfig.get()),
                            OmegaConf.to_container(cfg, resolve=True))))
        return preflight(cfg, *args, **kwargs)

    patch.setattr(job, "preflight", seen)
    return given


class Given(tuple):
    cfg = property(lambda self: self[0])
    hydra = property(lambda self: self[1])
    resolved = property(lambda self: self[2])


def job_of(dry_runs: dict, override: str) -> tuple:
    return next(done for overrides, done in dry_runs.items() if override in overrides)


def test_every_group_has_levels_and_cases_and_experiments_exist():
    assert len(LEVELS) >= 2 * len(GROUPS) - 4  # garage, renderer, tracking have one level; the rest several
    assert {"1", "2", "3"} <= {lv for g, lv in LEVELS if g == "case"}
    assert EXPERIMENTS == ["case3_table", "cpnco", "cpra", "light_sensor", "light_table"]


def test_every_level_is_in_a_dry_run_job_with_no_level_it_overrides():
    jobs = dry_run_jobs()
    held = sorted((g, lv) for job in jobs for g, lv in job.items() if g != "+experiment")
    assert sorted(set(held)) == sorted(LEVELS) and len(jobs) < len(LEVELS) / 3
    repeated = [x for x in held if held.count(x) > 1]  # the default plan, and a case of two experiments
    assert {g for g, _ in repeated} <= {"plan", "case"} and ("plan", "research") in repeated
    assert sorted(j["+experiment"] for j in jobs if "+experiment" in j) == EXPERIMENTS
    for job in jobs:
        levels = [(g, lv) for g, lv in job.items() if g != "+experiment"]
        assert not any(overridden(g, lv) & set(job) for g, lv in levels), job
        if job["plan"] != "research":  # a case, or a level that needs the default plan's wide bays, runs on it
            assert "case" not in job and not any(f"{g}={lv}" in WIDE_BAYS for g, lv in job.items()), job
        if "+experiment" in job:  # with the case it names, and no level of a group it overrides
            assert job["case"] == experiment_case(job["+experiment"]), job
            assert not (overridden("experiment", job["+experiment"]) - {"case"}) & set(job), job


@pytest.mark.parametrize("group,level", LEVELS, ids=[f"{g}={lv}" for g, lv in LEVELS])
def test_level_composes_with_its_file_values(group, level, dry_runs):
    """The config composed with the level (in its dry run's job) holds every value the level's file sets (under
    modifiers.<group> for the extra factors packaged there; the schema may add defaults beside them), and passes
    the schema check (no key past the schema: test_schema_check)."""
    from garage_exp.core.schema_check import check_schema

    args, given, proc, _ = job_of(dry_runs, f"{group}={level}")
    assert given is not None, proc.stderr[-3000:]
    cfg = given.cfg
    check_schema(cfg)
    text = (CONF / group / f"{level}.yaml").read_text()
    package = level_package(group, level)
    given = {a.split("=", 1)[0] for a in args}  # what the command line sets itself (the job's tracking.uri)
    data = {k: v for k, v in (yaml.safe_load(text) or {}).items() if k != "defaults" and f"{package}.{k}" not in given}
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
def test_experiment_composes_its_sweep(experiment, dry_runs):
    from garage_exp.core.schema_check import check_schema

    _, given, proc, _ = job_of(dry_runs, f"+experiment={experiment}")
    assert given is not None, proc.stderr[-3000:]
    cfg = given.cfg
    check_schema(cfg)
    spec = yaml.safe_load((CONF / "experiment" / f"{experiment}.yaml").read_text())
    assert dict(given.hydra.sweeper.params) == spec["hydra"]["sweeper"]["params"]
    assert cfg.tracking.experiment == spec["tracking"]["experiment"]
    override = next(d for d in spec["defaults"] if isinstance(d, dict))
    assert str(cfg.case.name) == str(next(iter(override.values())))


def test_dry_run_with_every_level_and_experiment(dry_runs):
    """A plan-only job (dry_run=true) with each level of each group (in the jobs of dry_run_jobs) and with each
    +experiment= finishes: the product's own checks accept it and it writes its config, which holds what each of
    its levels composes to, and its plan map."""
    for overrides, (args, given, proc, run) in dry_runs.items():
        assert proc.returncode == 0, (overrides, proc.stderr[-3000:])
        written = OmegaConf.load(run / "config.yaml")
        for override in overrides:
            group, level = override.lstrip("+").split("=")
            if group == "experiment":
                spec = yaml.safe_load((CONF / "experiment" / f"{level}.yaml").read_text())
                assert written.tracking.experiment == given.cfg.tracking.experiment == spec["tracking"]["experiment"]
                continue
            # the job ran with the level (test_level_composes_with_its_file_values: the config it was given holds
            # the file's values): its written config holds what the level composed to, at its package
            package = level_package(group, level)
            package = group if package == "_global_" else package  # a preset (look=): its own node suffices
            expected = OmegaConf.select(OmegaConf.create(given.resolved), package)
            expected = OmegaConf.to_container(expected) if expected is not None else None
            got = OmegaConf.to_container(OmegaConf.select(written, package), resolve=True)
            if override == "plan=generated":  # logged as the plan drawn (plan.name, as with plan.file)
                assert got["name"] == f"generated_{expected['generator']['family']}_{expected['seed']}"
                expected["name"] = got["name"]
            assert expected and holds(got, expected), (override, overrides, package, got, expected)
        assert (run / "plan_map.png").stat().st_size > 1000, overrides


def level_package(group: str, level: str) -> str:
    """Where a level's file puts its values: its `# @package` line, else its group."""
    text = (CONF / group / f"{level}.yaml").read_text()
    return text.split("# @package ", 1)[1].split()[0] if "# @package " in text else group
