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
         "browser": ("browser",)}
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
            elif capability == "vehicles":
                from garage_exp.assets.locate import vehicles_dir

                vehicles_dir()
            else:
                from garage_exp.perception.detect.detector import resolve_model

                absent = [m for m in default_models() if not resolve_model(m).exists()]
                problem = f"detector models missing: {absent}" if absent else None
        except GarageError as exc:
            problem = str(exc)
        _have[capability] = problem
    return _have[capability]


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
    """Skip, with the reason, when the machine lacks one of "vulkan", "vehicles", "models", "browser"; under CI=true or
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


@pytest.fixture
def mlflow_uri(tmp_path) -> str:
    return f"sqlite:///{tmp_path / 'mlflow.db'}"


def compose_cfg(*overrides: str, hydra: bool = False):
    """The job's config as `python -m garage_exp OVERRIDES` composes it (numeric case levels quoted as the CLI
    does); hydra=True keeps the hydra node (sweeper params, launcher)."""
    from hydra import compose, initialize_config_dir

    from garage_exp.core import schema
    from garage_exp.cli.app import quote_numeric_choices

    schema.register()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=quote_numeric_choices(list(overrides)),
                       return_hydra_config=hydra)


def child_env(env: dict | None = None) -> dict:
    """os.environ with env on top; a PYTHONPATH in env is put before the inherited one (which may point at
    the checkout under test), not in its place."""
    full = {**os.environ, **(env or {})}
    if env and env.get("PYTHONPATH") and os.environ.get("PYTHONPATH"):
        full["PYTHONPATH"] = os.pathsep.join([env["PYTHONPATH"], os.environ["PYTHONPATH"]])
    return full


def run_app(args: list[str], tmp_path: Path, env: dict | None = None, timeout: int = 600):
    """Run `python -m garage_exp` in a subprocess with outputs under tmp_path."""
    import subprocess

    full_env = child_env(env)
    cmd = [PYTHON, "-m", "garage_exp", *args,
           f"hydra.run.dir={tmp_path}/run", f"hydra.sweep.dir={tmp_path}/sweep"]
    return subprocess.run(cmd, cwd=tmp_path, env=full_env, capture_output=True, text=True, timeout=timeout)


def cli_forked(argv: list[str], cwd: Path, env: dict | None = None):
    """`python -m garage_exp ARGV` in a child forked from this process, as tests/cli_forkserver.py runs it (no
    interpreter start-up), so that what the test patched or put on sys.path here holds there too. Only the
    command's own work runs in the child; the detectors still run in their own process. Outputs under cwd (hydra
    dirs as run_app's unless ARGV names them); stdout and stderr come back as a CompletedProcess's."""
    import subprocess
    import tempfile

    import cli_forkserver

    given = {a.split("=", 1)[0] for a in argv}
    dirs = [d for d in (f"hydra.run.dir={cwd}/run", f"hydra.sweep.dir={cwd}/sweep") if d.split("=")[0] not in given]
    argv = [*argv, *dirs]
    with tempfile.TemporaryDirectory() as scratch:
        request = {"argv": argv, "cwd": str(cwd), "env": env or {}, "stdout": f"{scratch}/out",
                   "stderr": f"{scratch}/err"}
        pid = os.fork()
        if pid == 0:
            code = 70
            try:
                from hydra.core.global_hydra import GlobalHydra

                from garage_exp.core.state import STATE

                GlobalHydra.instance().clear()
                STATE.renderer = STATE.detector = None  # this process's warm renderer and detector stay its own
                code = cli_forkserver.child(request)
            finally:
                os._exit(code)
        _, status = os.waitpid(pid, 0)
        return subprocess.CompletedProcess(argv, os.waitstatus_to_exitcode(status), Path(request["stdout"]).read_text(),
                                           Path(request["stderr"]).read_text())
