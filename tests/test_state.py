"""The process state (core.state.STATE) is the one home of the package's caches: every module-level cache and
memo is registered on it with its scope, and clearing a scope empties what belongs to it."""

import ast
import os
from pathlib import Path

import numpy as np
import pytest

from garage_exp.core.state import STATE, ProcessState

PACKAGE = Path(__file__).resolve().parents[1] / "garage_exp"
MUTATORS = {"append", "update", "setdefault", "pop", "clear", "add", "extend", "insert", "popitem", "discard",
            "remove", "__setitem__"}


def _is_state_call(node) -> bool:
    """`STATE.cache(...)` or a value built around it (`Loaded(STATE.cache(...))`)."""
    return any(isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "STATE"
               for n in ast.walk(node))


def stray_caches(root: Path) -> list[str]:
    """Module-level caches STATE does not know: an `lru_cache`/`functools.cache` memo, a name rebound through
    `global`, or a module-level container filled by a function (one named `register*` fills a registry, which
    is not a cache)."""
    found = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        where = path.relative_to(root.parent)
        top = {}
        for node in tree.body:
            if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
                for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                    if isinstance(target, ast.Name) and not _is_state_call(node.value):
                        top[target.id] = node.lineno
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for deco in fn.decorator_list:
                text = ast.unparse(deco)
                if any(word in text for word in ("lru_cache", "functools.cache", "cache")) and not (
                        text.startswith("STATE.") or "cached_property" in text):
                    found.append(f"{where}:{fn.lineno} {fn.name}: @{text} (use @STATE.memo(scope))")
            if fn.name.startswith("register"):
                continue
            for node in ast.walk(fn):
                name = None
                if isinstance(node, ast.Global):
                    found += [f"{where}:{node.lineno} global {n} (use STATE.cache(name, scope))" for n in node.names]
                elif isinstance(node, (ast.Assign, ast.AugAssign, ast.Delete)):
                    for target in getattr(node, "targets", None) or [node.target]:
                        if isinstance(target, ast.Subscript) and isinstance(target.value, ast.Name):
                            name = target.value.id
                elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                      and node.func.attr in MUTATORS and isinstance(node.func.value, ast.Name)):
                    name = node.func.value.id
                if name in top and not _local(fn, name):
                    found.append(f"{where}:{top[name]} {name} filled by {fn.name}() (use STATE.cache(name, scope))")
    return sorted(set(found))


def _local(fn, name: str) -> bool:
    """`name` is bound inside the function (a local that shadows the module's name)."""
    return any(isinstance(n, ast.Name) and n.id == name and isinstance(n.ctx, ast.Store) for n in ast.walk(fn)) or \
        any(a.arg == name for a in fn.args.args + fn.args.kwonlyargs)


def test_no_module_level_cache_outside_state():
    assert stray_caches(PACKAGE) == []


def test_the_scan_finds_a_stray_cache(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "m.py").write_text("import functools\n_SEEN = {}\n_MODEL = None\n\n"
                              "@functools.lru_cache(maxsize=4)\ndef f(x):\n    return x\n\n"
                              "def g(k):\n    _SEEN[k] = 1\n\n"
                              "def h():\n    global _MODEL\n    _MODEL = 1\n\n"
                              "KINDS = []\ndef register(k):\n    KINDS.append(k)\n")
    found = stray_caches(pkg)
    assert len(found) == 3 and [w for w in found if "lru_cache" in w] and [w for w in found if "_SEEN" in w] \
        and [w for w in found if "global _MODEL" in w]


def test_scopes_clear_what_belongs_to_them():
    state = ProcessState()
    kept = {scope: state.cache(f"test.{scope}", scope) for scope in ("process", "command", "job")}
    calls = []

    @state.memo("process", maxsize=4)
    def square(x):
        calls.append(x)
        return x * x

    def fill():
        for store in kept.values():
            store["k"] = 1
        square(3)

    fill()
    state.finished_jobs, state.stopping = 2, True
    state.begin_job()
    assert (kept["process"], kept["command"], kept["job"]) == ({"k": 1}, {"k": 1}, {})
    assert state.finished_jobs == 2
    fill()
    state.begin()  # a new command: command and job scope go, the process keeps its memo
    assert (kept["process"], kept["command"], kept["job"]) == ({"k": 1}, {}, {})
    assert (state.finished_jobs, state.stopping) == (0, False)
    square(3)
    assert calls == [3]
    state.plans["p"] = 1
    state.clear("process")
    assert kept == {"process": {}, "command": {}, "job": {}} and state.plans == {}
    square(3)
    assert calls == [3, 3]
    with pytest.raises(ValueError, match="scope must be one of"):
        state.cache("test.bad", "forever")


def test_the_package_registers_its_caches_on_state():
    from garage_exp.render import device  # noqa: F401 - registers on import
    from garage_exp.scene import textures
    from garage_exp.search import sweep

    assert STATE.registered["search.sweep.checked"][0] == "command"
    assert STATE.registered["render.device"][0] == "process"
    assert STATE.registered["garage_exp.scene.textures.image"][0] == "process"
    sweep._CHECKED[("test",)] = None
    textures.image.cache_clear()
    STATE.begin()
    assert ("test",) not in sweep._CHECKED


def _worker_children() -> list[int]:
    """This process's detector children (python -m garage_exp.perception.detect.worker)."""
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1]) == os.getpid() \
                    and b"garage_exp.perception.detect.worker" in (proc / "cmdline").read_bytes():
                pids.append(int(proc.name))
        except (OSError, IndexError, ValueError):
            continue
    return pids


@pytest.mark.detect
def test_the_prescreen_and_the_job_share_one_warm_detector(monkeypatch):
    """With the detector pre-screen the models load once, in the job's detector child: not a second time in
    this process."""
    from test_detect import bus_image, default_models

    import garage_exp.perception.detect as detect
    from garage_exp.perception.detect.base import LOADED
    from garage_exp.perception.detect.detector import Detector
    from garage_exp.perception.detect.worker import open_detector
    from garage_exp.search import prescreen

    monkeypatch.setenv("GARAGE_EXP_DETECT_PROCESS", "1")
    full = Detector(default_models(), classes=("car", "truck", "bus"), conf=0.05, imgsz=640, device="cpu")
    monkeypatch.setattr(detect, "build_detector", lambda conf: full)
    loaded_here = set(LOADED.models)
    cheap = prescreen.cheap_detector(None, 0.5)
    _, rgb = bus_image()
    found = cheap.detect([rgb])[0]
    assert [d.model for d in found] == cheap.names == full.cheap(0.5).names
    assert set(LOADED.models) == loaded_here  # nothing loaded in this process
    warm = STATE.detector
    assert warm is not None and _worker_children() == [warm.pid]
    assert open_detector(full) is warm and warm.names == full.names  # the job's detector: the same child
    assert [d.model for d in cheap.detect([rgb])[0]] == cheap.names  # the pre-screen's own again, after the job's
    assert _worker_children() == [warm.pid]
    ours = full.cheap(0.5).detect([rgb])[0]  # the same detections as in-process
    for a, b in zip(found, ours):
        assert a.classes == b.classes
        np.testing.assert_allclose(a.scores, b.scores, atol=1e-6)


# --- the process environment and process resources: set for a scope, put back when it is cleared (issue 41, item 5)

def env_writes(root: Path) -> list[str]:
    """Writes to os.environ outside core/state.py: `os.environ[...] = `, `os.environ.setdefault/update/pop(...)`,
    `del os.environ[...]`, `os.putenv`/`os.unsetenv`."""
    found = []
    for path in sorted(root.rglob("*.py")):
        if path.name == "state.py" and path.parent.name == "core":
            continue
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            text = None
            if isinstance(node, (ast.Assign, ast.AugAssign, ast.Delete)):
                for target in getattr(node, "targets", None) or [node.target]:
                    if isinstance(target, ast.Subscript) and ast.unparse(target.value) == "os.environ":
                        text = ast.unparse(node)
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                called = ast.unparse(node.func)
                if called in ("os.putenv", "os.unsetenv") or (
                        called.startswith("os.environ.") and node.func.attr in MUTATORS):
                    text = ast.unparse(node)
            if text:
                found.append(f"{path.relative_to(root.parent)}:{node.lineno} {text}")
    return found


def test_the_package_writes_the_environment_only_through_state():
    assert env_writes(PACKAGE) == []


def test_the_scan_finds_a_stray_environment_write(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "m.py").write_text("import os\nos.environ['A'] = '1'\nos.environ.setdefault('B', '2')\n"
                              "del os.environ['C']\nx = os.environ.get('D')\n")
    assert len(env_writes(pkg)) == 3


def test_setenv_is_put_back_when_its_scope_is_cleared(monkeypatch):
    state = ProcessState()
    monkeypatch.setenv("GARAGE_TEST_KEPT", "user")
    monkeypatch.delenv("GARAGE_TEST_NEW", raising=False)
    monkeypatch.delenv("GARAGE_TEST_PROC", raising=False)
    monkeypatch.delenv("GARAGE_TEST_LIB", raising=False)
    state.setenv("GARAGE_TEST_LIB", "set by a library call", "command")  # outside a command: simply set
    state.begin()
    assert os.environ["GARAGE_TEST_LIB"] == "set by a library call"
    state.setenv("GARAGE_TEST_KEPT", "command's", "command")
    state.setenv("GARAGE_TEST_KEPT", "again", "command")  # the first earlier value is what comes back
    state.setenv("GARAGE_TEST_NEW", "x", "job")
    assert state.setenv("GARAGE_TEST_KEPT", "ignored", "job", default=True) == "again"
    state.setenv("GARAGE_TEST_PROC", "p", "process")
    state.begin_job()
    assert "GARAGE_TEST_NEW" not in os.environ and os.environ["GARAGE_TEST_KEPT"] == "again"
    state.end()
    assert os.environ["GARAGE_TEST_KEPT"] == "user" and os.environ["GARAGE_TEST_PROC"] == "p"
    assert os.environ["GARAGE_TEST_LIB"] == "set by a library call"
    state.clear("process")
    assert "GARAGE_TEST_PROC" not in os.environ
    with pytest.raises(ValueError, match="scope must be one of"):
        state.setenv("GARAGE_TEST_NEW", "x", "forever")


def test_a_command_takes_the_environment_as_its_caller_left_it(monkeypatch):
    """What a caller sets between commands (a test's run_app, a user's shell) is not undone by the next command's
    begin, even when a stale command scope recorded the variable (test_world_faults' server-away test met this)."""
    state = ProcessState()
    monkeypatch.setenv("GARAGE_TEST_URI", "first")
    state.begin()
    state.setenv("GARAGE_TEST_URI", "the command's", "command")  # recorded: "first" comes back at the end
    os.environ["GARAGE_TEST_URI"] = "set by the caller"  # as if the command ended without end()
    state.begin()
    assert os.environ["GARAGE_TEST_URI"] == "set by the caller"
    state.end()
    assert os.environ["GARAGE_TEST_URI"] == "set by the caller"


def test_a_command_leaves_the_tracking_store_and_logging_as_it_found_them(monkeypatch, tmp_path):
    """prepare_environment sets $MLFLOW_TRACKING_URI for the command (its workers inherit it); STATE.end puts
    back the one before, and the shell puts back logging.raiseExceptions."""
    import logging

    from garage_exp.core.environment import prepare_environment
    from garage_exp.core.shell import Command
    from garage_exp.verify import schema

    monkeypatch.setenv("MLFLOW_TRACKING_URI", "sqlite:///before.db")
    monkeypatch.delenv("MLFLOW_HTTP_REQUEST_TIMEOUT", raising=False)
    seen = {}

    def task(cfg):
        prepare_environment("http://127.0.0.1:1")
        seen.update(uri=os.environ["MLFLOW_TRACKING_URI"], timeout=os.environ.get("MLFLOW_HTTP_REQUEST_TIMEOUT"),
                    raise_exceptions=logging.raiseExceptions)

    monkeypatch.chdir(tmp_path)
    assert logging.raiseExceptions is True
    Command("test", "verify", (schema.register,)).run(task, [f"hydra.run.dir={tmp_path}"])
    assert seen == {"uri": "http://127.0.0.1:1", "timeout": "30", "raise_exceptions": False}
    assert os.environ["MLFLOW_TRACKING_URI"] == "sqlite:///before.db"
    assert "MLFLOW_HTTP_REQUEST_TIMEOUT" not in os.environ and logging.raiseExceptions is True


def test_clearing_the_process_closes_its_detector_and_drops_its_renderer():
    state = ProcessState()
    closed = []

    class Child:
        def close(self):
            closed.append(True)

    state.detector, state.renderer = Child(), object()
    state.clear("command")
    assert state.detector is not None and state.renderer is not None  # warm across commands
    state.clear("process")
    assert closed == [True] and state.detector is None and state.renderer is None
