import contextlib
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PYTHON = sys.executable

# Tests never reach for the network and never write into the user's MLflow store.
os.environ.setdefault("YOLO_OFFLINE", "1")
os.environ.pop("MLFLOW_TRACKING_URI", None)
# MLflow 3's `mlflow ui`/`mlflow server` start about seven job consumers (huey) for GenAI jobs no test uses; on
# 2 cores they take CPU from the test that started the server.
os.environ.setdefault("MLFLOW_SERVER_ENABLE_JOB_EXECUTION", "false")
# The slot truth's floats (tests/golden/exports.json) go through numpy's matrix products, and OpenBLAS picks its
# kernels by CPU: its AVX-512 (SkylakeX) kernels on a Zen 4 round the last digits otherwise than its AVX2 (Haswell)
# ones on a Zen 5, which wrote the pinned bytes (measured: OPENBLAS_CORETYPE=Haswell or Zen on the Zen 4 writes
# them, SkylakeX or Cooperlake do not). The tests pin the kernels so that one set of bytes holds on both; read when
# numpy loads OpenBLAS, so before anything imports numpy (xdist's workers inherit it).
if "numpy" not in sys.modules and " avx2 " in (Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").is_file()
                                                else ""):
    os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")  # AVX2 kernels: only where the CPU has AVX2
# `make test` sets GARAGE_EXP_PROVISIONED=1 after provisioning Vulkan, vehicles and weights (make setup).
STRICT_CI = os.environ.get("CI", "").lower() == "true" or os.environ.get("GARAGE_EXP_PROVISIONED") == "1"

from garage_exp.perception.detect import prepare_offline  # noqa: E402

prepare_offline()


# --- skips that must not hide failures ----------------------------------------------------------------------------
# A `render`, `detect` or `slow` test may skip only on a machine that lacks what it needs (a Vulkan device, the
# vehicle models, the detector weights). Where the machine has it (as after `make test`, which provisions all
# three) or under CI=true, such a skip is an error carrying the skip's reason: a bug in the asset lookup or the
# device check then fails the suite instead of silently skipping it. CI is read before prepare_offline() above
# may set it for openvino's sake.
NEEDS = {"render": ("vulkan",), "detect": ("models",), "slow": ("vulkan", "vehicles", "models"),
         "browser": ("browser",), "cluster": ("cluster",)}
CHROMIUM = ("chromium", "chromium-browser")  # Debian's package (scripts/setup_browser.sh), Ubuntu's name
_have: dict[str, str | None] = {}


def missing(capability: str) -> str | None:
    """Why the machine lacks the capability, or None when it has it (found through the product's own lookup)."""
    if capability not in _have:
        from garage_exp.core.errors import GarageError

        problem = None
        try:
            if capability == "vulkan":
                from garage_exp.render.device import device_problem

                problem = device_problem()
            elif capability == "browser":
                problem = browser_problem()
            elif capability == "cluster":
                from cluster import cluster_problem

                problem = cluster_problem()
            elif capability == "asam-qc":
                from tools.asam_qc import qc_bin

                qc_bin()
            elif capability == "esmini":
                from tools.esmini import esmini_path

                esmini_path()
            elif capability == "vehicles":
                from garage_exp.assets.locate import vehicles_dir

                vehicles_dir()
            elif capability == "street-photos":
                from garage_exp.assets.photos import street_photos

                street_photos()
            else:
                from garage_exp.perception.detect.entries import resolve

                absent = [m for m in default_models() if not Path(resolve(m)).exists()]
                problem = f"detector models missing: {absent}" if absent else None
        except GarageError as exc:
            problem = str(exc)
        _have[capability] = problem
    return _have[capability]


def instruction_set() -> str:
    """The CPU feature that decides numeric kernels: OpenVINO's INT8 detectors pick AMX, AVX-512 VNNI, AVX-VNNI or
    AVX2 kernels, which round differently, and the slot truth's floats differ in their last digits between AVX-512
    and AVX2 machines, so a few pinned outputs hold one set per kind of machine (tests/golden/<set>/). AMX comes
    first: an Intel Xeon with it has AVX-512 VNNI too, and its detectors' scores moved by up to 0.004 from the
    Zen 4's on the lighting table (measured, 2026-12-08)."""
    try:
        flags = set(Path("/proc/cpuinfo").read_text().split())
    except OSError:
        return "unknown"
    if "amx_int8" in flags:
        return "amx"
    return "avx512" if "avx512_vnni" in flags else "avxvnni" if "avx_vnni" in flags else "avx2"


def chromium() -> str | None:
    import shutil

    return next((path for name in CHROMIUM if (path := shutil.which(name))), None)


def browser_problem() -> str | None:
    """Why Playwright cannot drive a browser here: it drives the system's chromium (its own download cannot
    work here), so both must be installed."""
    import importlib.util

    if chromium() is None:
        return f"no chromium on PATH (looked for {', '.join(CHROMIUM)}; scripts/setup_browser.sh installs it)"
    if importlib.util.find_spec("playwright") is None:
        return "the playwright package is not installed (pip install -e '.[test]')"
    return None


def require(*capabilities: str) -> None:
    """Skip, with the reason, when the machine lacks one of "vulkan", "vehicles", "models", "browser", "cluster",
    "street-photos" (the loop's second real-photo set, fetched by `make data`),
    "esmini" (the OpenSCENARIO player in ../shared/tools), "asam-qc" (ASAM's checker bundles in .venv-qc); under CI=true or
    `make test` (STRICT_CI) fail instead, whatever the test's markers."""
    for capability in capabilities:
        problem = missing(capability)
        if problem and STRICT_CI:
            pytest.fail(f"{capability} missing under CI=true or make test: {problem}")
        if problem:
            pytest.skip(f"{capability}: {problem}")


def default_models() -> list[str]:
    """The model entries of the default detector config (conf/detector/coco3.yaml)."""
    import yaml

    return yaml.safe_load((ROOT / "conf" / "detector" / "coco3.yaml").read_text())["models"]


def skips_are_errors(item) -> bool:
    needs = {c for mark, caps in NEEDS.items() if item.get_closest_marker(mark) for c in caps}
    if not needs:
        return False
    return STRICT_CI or all(missing(c) is None for c in needs)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.skipped and not hasattr(report, "wasxfail") and skips_are_errors(item):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        reason = reason.removeprefix("Skipped: ")
        why = "CI=true or make test" if STRICT_CI else "this machine has the Vulkan device, vehicles and weights it needs"
        report.outcome = "failed"
        report.longrepr = f"skip is an error here ({why}): {reason}"


# --- the slowest files first ---------------------------------------------------------------------------------------
# `make test` runs `--dist loadfile --no-loadscope-reorder`: xdist hands each worker a whole file at a time in
# collection order. Ordering the files by their measured seconds (tests/file_seconds.json, written from a JUnit
# report by scripts/file_seconds.py), longest first, is the greedy schedule for two workers: no 100 s file is left
# to run alone at the end. A file not in the table (new) counts as its number of tests in seconds. Within a file
# the order is unchanged.
def file_order_key(weights: dict[str, float], counts: dict[str, int]):
    return lambda path: -weights.get(path, float(counts[path]))


def pytest_collection_modifyitems(session, config, items):
    import json

    table = ROOT / "tests" / "file_seconds.json"
    weights = json.loads(table.read_text()) if table.is_file() else {}
    counts: dict[str, int] = {}
    for item in items:
        path = item.nodeid.split("::", 1)[0]
        counts[path] = counts.get(path, 0) + 1
    key = file_order_key(weights, counts)
    items[:] = sorted(items, key=lambda item: key(item.nodeid.split("::", 1)[0]))  # stable: a file's order kept


@pytest.fixture
def mlflow_uri(tmp_path) -> str:
    return f"sqlite:///{tmp_path / 'mlflow.db'}"


# --- configs composed as the commands compose them -----------------------------------------------------------------
def compose_cfg(*overrides: str, hydra: bool = False, config: str = "config", config_dir=None):
    """The config as the command reading conf/<config>.yaml composes it from OVERRIDES (`config`: the main
    command's "config", or "gym", "train", "loop", "verify"), through the commands' own shell (its schemas, the
    resolvers, numeric case levels quoted); hydra=True keeps the hydra node (sweeper params, launcher);
    config_dir: a folder of the user's own levels searched too (hydra.searchpath)."""
    from garage_exp.core import shell

    extra = [f"hydra.searchpath=[file://{config_dir}]"] if config_dir else []
    return shell.compose(config, [*extra, *overrides], schemas=command_schemas(config), hydra=hydra)


def command_schemas(config: str) -> tuple:
    """The schemas the command reading conf/<config>.yaml registers (its shell.Command's); the experiment's
    `Config` assembled first, as the main command's module does on import (garage_exp/config.py)."""
    import importlib

    import garage_exp.config  # noqa: F401
    if config == "config":
        return ()

    return importlib.import_module(f"garage_exp.{config}.app").COMMAND.schemas


@contextlib.contextmanager
def hydra_loader(config: str = "config"):
    """Hydra initialised on conf/ as a command's run has it, for tests that use its config loader (a sweep's
    jobs, the search's cached composition); cleared after."""
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from garage_exp.core import shell

    shell.register(*command_schemas(config))
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(shell.CONF_DIR), version_base="1.3"):
        yield GlobalHydra.instance().config_loader()


def recording_launch(launched: list, frames: float = 1.0):
    """A search's launch whose jobs are stand-ins: each batch's overrides appended to `launched`, each job
    returning a complete trial's summary (`frames` fair frames, difficulty 0.5)."""
    from types import SimpleNamespace

    def launch(batch, idx):
        launched.extend(batch)
        return [SimpleNamespace(return_value={"fair_frames": frames, "fair_difficulty": 0.5, "fair_confidence": 0.5,
                                              "fair_recall": 1.0, "visible_fraction_mean": 0.9, "frames": frames,
                                              "run_id": "r", "output_dir": "/nowhere"}) for _ in batch]

    return launch


def schema_node(schema, values: dict):
    """A config group's node as its schema types it (`schema`: the dataclass), with `values` set: what Hydra
    composes for one level, without composing the whole config."""
    from omegaconf import OmegaConf

    return OmegaConf.merge(OmegaConf.structured(schema), values)


def child_env(env: dict | None = None) -> dict:
    """os.environ with env on top; a PYTHONPATH in env is put before the inherited one (which may point at
    the checkout under test), not in its place."""
    full = {**os.environ, **(env or {})}
    if env and env.get("PYTHONPATH") and os.environ.get("PYTHONPATH"):
        full["PYTHONPATH"] = os.pathsep.join([env["PYTHONPATH"], os.environ["PYTHONPATH"]])
    return full


# --- the command line, in this process or a fresh one ---------------------------------------------------------------
# A fresh `python -m garage_exp` pays ~5 s of imports, a new MLflow store's migrations (~4 s) and, for a job that
# renders, SAPIEN's shader compilation on lavapipe (10-30 s) and the detectors' loading. Most tests are about what
# a job or a sweep does, not about the interpreter: they run the command line in this process, as __main__ does
# (garage_exp.cli.app.cli, whose STATE keeps the renderer and the detector warm between jobs), on a store copied
# from one migrated template. Tests about the process itself (signals, fault injection through sitecustomize on
# PYTHONPATH, a fresh interpreter's output) pass process=True, or are sent to a subprocess by their env.
_TEMPLATE: list[Path] = []


def store_template() -> Path:
    """An empty MLflow sqlite store, migrated once per test session."""
    if not _TEMPLATE:
        import tempfile

        from garage_exp.tracking import runs as tracking

        path = Path(tempfile.mkdtemp(prefix="garage_store_")) / "mlflow.db"
        tracking.client(f"sqlite:///{path}").search_experiments()
        _TEMPLATE.append(path)
    return _TEMPLATE[0]


def seed_store(args: list[str], cwd: Path) -> None:
    """Copy the migrated template to a sqlite store the command names that does not exist yet."""
    import shutil

    for arg in args:
        if arg.startswith("tracking.uri=sqlite:///"):
            path = Path(arg.split("sqlite:///", 1)[1])
            path = path if path.is_absolute() else cwd / path
            if not path.exists() and path.parent.is_dir():
                shutil.copyfile(store_template(), path)


def run_app(args: list[str], tmp_path: Path, env: dict | None = None, timeout: int = 600, process: bool = False,
            fresh_store: bool = False):
    """`python -m garage_exp ARGS` with outputs under tmp_path, as a CompletedProcess (returncode, stdout,
    stderr). In this process (env's PYTHONPATH put before sys.path for the call) unless process=True, env's
    PYTHONPATH holds a sitecustomize (code only a starting interpreter runs) or the caller is not the main
    thread (a job runs beside another); an absent sqlite store the command names starts from the template
    unless fresh_store=True."""
    cmd = [*args, f"hydra.run.dir={tmp_path}/run", f"hydra.sweep.dir={tmp_path}/sweep"]
    if not fresh_store:
        seed_store(cmd, tmp_path)
    import threading

    paths = [p for p in (env or {}).get("PYTHONPATH", "").split(os.pathsep) if p]
    startup = any((Path(p) / "sitecustomize.py").is_file() for p in paths)  # runs only when an interpreter starts
    if process or startup or threading.current_thread() is not threading.main_thread():
        import subprocess  # signal handlers can only be installed from the main thread

        return subprocess.run([PYTHON, "-m", "garage_exp", *cmd], cwd=tmp_path, env=child_env(env),
                              capture_output=True, text=True, timeout=timeout)
    return run_in_process(cmd, tmp_path, env)


def run_in_process(args: list[str], cwd: Path, env: dict | None = None, entry=None):
    """What `python -m garage_exp ARGS` does, in this process: argv, working dir and environment set for the
    call and restored after it, stdout and stderr captured, SystemExit as the return code, an uncaught
    exception as its traceback and 1 (as the interpreter would). `entry`: another entry point's function
    (`garage_exp.train.app.cli`), run and cleaned up after the same way."""
    import contextlib
    import io
    import logging
    import subprocess

    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    from cli_forkserver import call_cli

    from garage_exp.core.state import STATE

    out, err = io.StringIO(), io.StringIO()
    saved = (dict(os.environ), os.getcwd(), sys.argv, list(sys.path))
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    os.environ.update(env or {})
    sys.path[:0] = [p for p in (env or {}).get("PYTHONPATH", "").split(os.pathsep) if p]
    os.chdir(cwd)
    sys.argv = [str(ROOT / "garage_exp" / "__main__.py"), *args]
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = call_cli(entry)
    finally:
        os.environ.clear()
        os.environ.update(saved[0])
        os.chdir(saved[1])
        sys.argv = saved[2]
        sys.path[:] = saved[3]
        GlobalHydra.instance().clear()
        HydraConfig.instance().cfg = None  # as in a new process: no job's Hydra config
        STATE.end()  # nor its command scope: sweep, counts, tracking outage, command caches (warm parts stay)
        root.handlers[:] = handlers  # Hydra's job logging configured the root logger for the call
        root.setLevel(level)
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


def run_module(module: str, args: list[str], cwd: Path, env: dict | None = None):
    """`python -m MODULE ARGS` (another command than garage_exp's: garage_exp.plan, garage_exp.report, ...), in
    this process as run_in_process runs the main one: the module run as __main__ (runpy, as -m does), argv,
    working dir and environment set for the call and restored after it, SystemExit as the return code."""
    import runpy

    return run_in_process(args, cwd, env, entry=lambda: runpy.run_module(module, run_name="__main__", alter_sys=True))


# --- a signal in the middle of a command, in this process -----------------------------------------------------------
def sigterm_here(*args, **kwargs):
    """Stands in for a command's long part (a training, a step, a scoring): SIGTERM to this process, as a
    scheduler's time limit sends it. The command's shell turns it into an exception right here (Terminated)."""
    import signal
    import time

    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(30)  # the handler raises before this ends
    raise AssertionError("SIGTERM was not handled")


def inject_fault(monkeypatch, spec: str) -> None:
    """What GARAGE_EXP_FAULT=SPEC (tests/faults/sitecustomize.py) injects into a new interpreter, here in this
    process for the test (undone with its monkeypatch), so the command runs through run_app on the warm renderer
    and detector. The hooks are tests/faults' own; each wraps an attribute garage_exp looks up at call time (the
    sensor maker a job builds by name, the job module's plan_map, DetectorProcess.submit), so wrapping the loaded
    module now is what wrapping it as it is first imported does in a new interpreter."""
    import importlib
    import importlib.util

    hooks = importlib.util.spec_from_file_location("faults_in_process", ROOT / "tests" / "faults" / "sitecustomize.py")
    faults = importlib.util.module_from_spec(hooks)
    monkeypatch.delenv("GARAGE_EXP_FAULT", raising=False)  # the hooks read it when loaded: none installed then
    hooks.loader.exec_module(faults)
    faults.after_import = lambda name, patch: patch(importlib.import_module(name))  # loaded already: patch now
    import garage_exp.perception.sensor as sensor
    import garage_exp.run.job as job
    from garage_exp.perception.detect import worker

    for owner, name in ((sensor, "make_sensor"), (job, "plan_map"), (worker.DetectorProcess, "submit")):
        monkeypatch.setattr(owner, name, getattr(owner, name))  # each put back after the test
    for one in filter(None, spec.split(";")):
        faults._install(one)


def run_statuses(uri: str, experiment: str) -> list[str]:
    """The status of every run in the store's experiment."""
    from garage_exp.tracking import runs as tracking

    mlc = tracking.client(uri)
    exp = mlc.get_experiment_by_name(experiment)
    return [r.info.status for r in mlc.search_runs([exp.experiment_id])] if exp else []


# --- a tracking server that does not answer -------------------------------------------------------------------------
class Refused(Exception):
    pass


REFUSED = Refused("API request to http://127.0.0.1:1/api/2.0/mlflow/runs/create failed with exception "
                  "HTTPConnectionPool(host='127.0.0.1', port=1): Max retries exceeded with url: ... "
                  "(Caused by NewConnectionError(...: Failed to establish a new connection: [Errno 111] "
                  "Connection refused'))")


@pytest.fixture
def fresh_outage(monkeypatch):
    """retry()'s outage state as in a new process, and sleeps that only count (the list of them)."""
    from garage_exp.core.state import STATE
    from garage_exp.tracking import client

    monkeypatch.setattr(STATE, "tracking_down_since", None)
    monkeypatch.setattr(STATE, "tracking_given_up", False)
    monkeypatch.setattr(STATE, "stopping", False)
    monkeypatch.setattr(client, "_uri", lambda: "http://127.0.0.1:1")
    slept = []
    clock = [1000.0]

    def sleep(s):
        slept.append(s)
        clock[0] += s

    monkeypatch.setattr(client.time, "sleep", sleep)
    monkeypatch.setattr(client.time, "monotonic", lambda: clock[0])
    return slept



def rerun_elite(elite, tmp_path: Path):
    """An archive elite's rerun command (archive.csv's `rerun`) run as a plain job in a fresh renderer, as a new
    process has; its frame table."""
    import shlex

    import pandas as pd

    from garage_exp.core.state import STATE

    STATE.renderer = None
    rerun_dir = tmp_path / f"rerun_{elite.trial}"
    rerun_dir.mkdir()
    command = shlex.split(elite.rerun)
    assert command[:3] == ["python", "-m", "garage_exp"]
    rerun = run_app([*command[3:], f"tracking.uri=sqlite:///{tmp_path / 'rerun.db'}"], rerun_dir)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    return pd.read_csv(rerun_dir / "run" / "frames.csv")
