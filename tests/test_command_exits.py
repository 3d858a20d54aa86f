"""Every command's exit codes, through the one shell (garage_exp.core.shell; issue 41, item 3): bad input is ONE line
on stderr starting with the command's name, exit 2, nothing written; SIGTERM is one line and exit 143.

Bad input runs in this process (conftest.run_in_process). The SIGTERM checks need a process of their own: each
command is started with an input that cannot be read until the test lets it (a FIFO nobody writes to, a store
whose lock the test holds, an `apt-get` that does not answer), and the signal is sent once the command waits on
it (/proc/PID: blocked opening the FIFO, asleep between tries of the lock, or with apt-get as its child), so the
command is surely in its shell and still running. (A signal in the middle of importing a C extension can be lost
inside the extension's own set-up, lxml's for one: no shell can see it, so the test does not signal there.)
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import PYTHON, ROOT, child_env, run_in_process

PACKAGE = ROOT / "garage_exp"

# Hydra commands: prog -> (module of `cli`, a bad input, what its line names)
HYDRA = {
    "garage_exp": ("garage_exp.cli.app", ["plan=no_such_plan"], "no_such_plan"),
    "garage_exp.gym": ("garage_exp.gym.app", ["gym.envs=0"], "gym.envs: 0 is outside 1-256"),
    "garage_exp.train": ("garage_exp.train.app", ["epochs=ten"], "'ten'"),
    "garage_exp.loop": ("garage_exp.loop.app", ["seeds=[first]"], "'first'"),
    "garage_exp.verify": ("garage_exp.verify.app", ["split=nope"], "split: 'nope' is not one of train, val, test"),
}
# argparse commands: prog -> (module of `main`, `python -m` module)
ARGPARSE = {
    "garage_exp.plan": ("garage_exp.plan.__main__", "garage_exp.plan"),
    "garage_exp.report": ("garage_exp.report", "garage_exp.report"),
    "garage_exp.report.search_analysis": ("garage_exp.report.search_analysis", "garage_exp.report.search_analysis"),
    "garage_exp.search.grade": ("garage_exp.search.grade", "garage_exp.search.grade"),
    "garage_exp.exports": ("garage_exp.exports.__main__", "garage_exp.exports"),
    "garage_exp.assets": ("garage_exp.assets.__main__", "garage_exp.assets"),
    "garage_exp.scenario.import": ("garage_exp.openscenario.xosc_import", "garage_exp.scenario.import"),
    "garage_exp.tracking.store": ("garage_exp.tracking.store", "garage_exp.tracking.store"),
    "garage_exp.tracking.ui": ("garage_exp.tracking.ui", "garage_exp.tracking.ui"),
}


def files_under(path: Path) -> set[str]:
    return {str(p.relative_to(path)) for p in path.rglob("*")}


def junk_store(tmp: Path) -> Path:
    path = tmp / "junk.db"
    path.write_bytes(b"not sqlite at all" * 100)
    return path


# prog -> (argv for a bad input in the folder, environment, what the line names)
BAD_ARGS = {
    "garage_exp.plan": lambda t: (["check", str(t / "missing.yaml")], {}, "missing.yaml: plan file not found"),
    "garage_exp.report": lambda t: (["--uri", f"sqlite:///{t / 'none.db'}", "-o", str(t / "out")], {},
                                    "none.db: no MLflow store here"),
    "garage_exp.report.search_analysis": lambda t: (["--storage", f"sqlite:///{t / 'none.db'}"], {},
                                                    "none.db: no such file"),
    "garage_exp.search.grade": lambda t: (["--storage", f"sqlite:///{t / 'none.db'}", "--study", "s"], {},
                                          "none.db: no such file"),
    "garage_exp.exports": lambda t: ([str(t)], {}, "no coco.json: not a dataset"),
    "garage_exp.assets": lambda t: (["convert"], {"GARAGE_EXP_ASSETS": str(t / "nowhere")},
                                    "GARAGE_EXP_ASSETS=" + str(t / "nowhere") + ": holds neither"),
    "garage_exp.scenario.import": lambda t: ([str(t / "none.xosc"), "-o", str(t / "case" / "x.yaml")], {},
                                             "none.xosc: cannot read it"),
    "garage_exp.tracking.store": lambda t: ([str(junk_store(t))], {}, "junk.db: not an MLflow sqlite store"),
    "garage_exp.tracking.ui": lambda t: (["--uri", f"sqlite:///{junk_store(t)}"], {},
                                         "junk.db: not an MLflow sqlite store"),
}


def test_every_command_is_checked_here_and_runs_in_the_one_shell():
    """Each module with an ArgumentParser is a command of ARGPARSE that hands its parser to the shell (it never
    parses, prints its errors or picks exit codes itself); each Hydra command is one of HYDRA."""
    import importlib

    from garage_exp.core import shell

    parsers = {str(p.relative_to(ROOT)) for p in PACKAGE.rglob("*.py") if "ArgumentParser(" in p.read_text()}
    assert parsers == {str(Path(*m.split("."))) + ("/__init__.py" if m == "garage_exp.report" else ".py")
                       for m, _ in ARGPARSE.values()}
    for path in parsers:
        source = (ROOT / path).read_text()
        assert "run_args(" in source and ".parse_args(" not in source and "print(f\"error" not in source, path
    hydra = {m for m in (str(p.relative_to(ROOT).with_suffix("")).replace("/", ".") for p in PACKAGE.rglob("app.py"))
             if isinstance(getattr(importlib.import_module(m), "COMMAND", None), shell.Command)}
    assert hydra == {m for m, _, _ in HYDRA.values()}


@pytest.mark.parametrize("prog", list(HYDRA) + list(ARGPARSE))
def test_bad_input_is_one_line_and_exit_2(prog, tmp_path):
    import importlib

    if prog in HYDRA:
        module, args, expect = HYDRA[prog]
        cli = importlib.import_module(module).cli
        argv, env = [*args, f"hydra.run.dir={tmp_path / 'run'}", f"tracking.uri=sqlite:///{tmp_path / 'm.db'}"], {}
        entry = lambda: cli(argv)  # noqa: E731
    else:
        main = importlib.import_module(ARGPARSE[prog][0]).main
        argv, env, expect = BAD_ARGS[prog](tmp_path)
        entry = lambda: sys.exit(main(argv))  # noqa: E731
    before = files_under(tmp_path)
    r = run_in_process([], tmp_path, env=env, entry=entry)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2, r.stderr[-3000:]
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: ") and expect in lines[0], r.stderr[-3000:]
    written = files_under(tmp_path) - before
    assert written <= {"junk.db.lock"}, sorted(written)  # the store's check takes its lock, writes nothing else


def test_a_usage_error_is_one_line_and_exit_2(capsys):
    """argparse's own errors (its usage block and `error:` line) become the shell's one line."""
    from garage_exp.plan.__main__ import main

    assert main(["drew"]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == ["garage_exp.plan: argument command: invalid choice: 'drew' (choose from 'map', "
                                "'check', 'generate', 'draw') (see python -m garage_exp.plan --help)"]
    assert main(["--help"]) == 0


# --- SIGTERM: a child process held at an input until the signal comes -------------------------------------------------
def catches(pid: int, sig: int) -> bool:
    """Whether the process has a handler of its own for `sig` (Python installs none for SIGTERM: the shell does)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (sig - 1) & 1)
    return False


def waiting(pid: int, on: str) -> bool:
    """Whether the process (its main thread) waits on its input: `fifo` blocked opening one, `lock` asleep between
    two tries of the store's lock, `child` with a child process (apt-get) it waits for."""
    proc = Path(f"/proc/{pid}")
    if on == "fifo":
        return (proc / "wchan").read_text() == "wait_for_partner"
    if on == "lock":  # filelock tries the lock, then sleeps before it tries again
        return (proc / "wchan").read_text() == "hrtimer_nanosleep"
    return bool((proc / "task" / str(pid) / "children").read_text().strip())


def fifo(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path)
    return path


def hydra_held(tmp: Path) -> list[str]:
    """Hydra opens the job's log file before the task: a FIFO there holds the command in its shell."""
    fifo(tmp / "run" / "exits.log")
    return [f"hydra.run.dir={tmp / 'run'}", "hydra.job.name=exits", f"tracking.uri=sqlite:///{tmp / 'm.db'}"]


def locked_store(tmp: Path, stack) -> Path:
    """A store whose lock this test holds: the command waits for it (tracking.store.open_store)."""
    from filelock import FileLock

    path = tmp / "store.db"
    path.touch()
    stack.enter_context(FileLock(f"{path}.lock"))
    return path


def study_storage(tmp: Path) -> str:
    import optuna

    storage = f"sqlite:///{tmp / 'study.db'}"
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(study_name="s", storage=storage, sampler=optuna.samplers.RandomSampler(seed=0))
    # two values of x: one would make optuna's slice plot warn (identical xlims) on stderr before the signal
    study.optimize(lambda t: t.suggest_float("x", 0, 1), n_trials=2)
    return storage


def slow_apt(tmp: Path) -> dict:
    """An apt-get that does not answer (a mirror away), and an empty cache: `assets fetch` waits on it."""
    bin_dir = tmp / "bin"
    bin_dir.mkdir()
    (bin_dir / "apt-get").write_text("#!/bin/sh\nexec sleep 300\n")
    (bin_dir / "apt-get").chmod(0o755)
    return {"PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "GARAGE_EXP_CACHE": str(tmp / "cache")}


def xosc(tmp: Path) -> Path:
    from xosc_files import EGO, PERSON, pedestrian, scenario, vehicle, write

    return write(tmp, "s.xosc", scenario(vehicle("Ego") + pedestrian("Walker"), {**EGO, **PERSON}))


def held(prog: str, tmp: Path, stack) -> tuple[list[str], dict, str]:
    """The command's arguments and environment that keep it waiting on an input, and what it waits on."""
    if prog in HYDRA:
        return hydra_held(tmp), {}, "fifo"
    if prog == "garage_exp.plan":
        for name in ("garage13x15", "garage26x30", "garage39x45"):
            fifo(tmp / "plans" / f"{name}.yaml")
        return ["generate", "-o", str(tmp / "plans")], {}, "fifo"
    if prog in ("garage_exp.report", "garage_exp.tracking.ui"):
        return ["--uri", f"sqlite:///{locked_store(tmp, stack)}"], {}, "lock"
    if prog == "garage_exp.tracking.store":
        return [str(locked_store(tmp, stack))], {}, "lock"
    if prog == "garage_exp.report.search_analysis":
        storage = study_storage(tmp)
        for name in ("hardest.csv", "trials.csv", "search_report.md"):  # text files (a PNG is opened w+b)
            fifo(tmp / "out" / name)
        return ["--storage", storage, "-o", str(tmp / "out")], {}, "fifo"
    if prog == "garage_exp.search.grade":  # it waits on the fresh draws' search, a child process
        storage = study_storage(tmp)
        import optuna

        optuna.load_study(study_name="s", storage=storage).set_user_attr("argv", ["plan=tiny", "dry_run=true"])
        return ["--storage", storage, "--study", "s", "--levels", "2", "--fresh", "1", "-o", str(tmp / "out")], {}, \
            "child"
    if prog == "garage_exp.exports":
        fifo(tmp / "slots" / "coco_keypoints.json")
        return [str(tmp / "slots"), "-o", str(tmp / "x.png")], {}, "fifo"
    if prog == "garage_exp.assets":
        return ["fetch"], slow_apt(tmp), "child"
    if prog == "garage_exp.scenario.import":
        return [str(xosc(tmp)), "-o", str(fifo(tmp / "case" / "s.yaml"))], {}, "fifo"
    raise AssertionError(prog)


def signalled(prog: str, tmp: Path, sig: int) -> subprocess.CompletedProcess:
    """The command run in a child process, held at its input, sent `sig` while it waits there."""
    import contextlib

    module = prog if prog in HYDRA else ARGPARSE[prog][1]
    with contextlib.ExitStack() as stack:
        argv, env, on = held(prog, tmp, stack)
        proc = subprocess.Popen([PYTHON, "-m", module, *argv], cwd=tmp, env=child_env(env),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        stack.callback(lambda: proc.poll() is None and proc.kill())
        while not waiting(proc.pid, on):
            assert proc.poll() is None, f"{prog} ended before the signal: {proc.communicate()[1][-3000:]}"
            time.sleep(0.01)
        assert catches(proc.pid, signal.SIGTERM)  # the shell's handler, while the command runs
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


@pytest.mark.parametrize("prog", list(HYDRA) + list(ARGPARSE))
def test_sigterm_is_one_line_and_exit_143(prog, tmp_path):
    r = signalled(prog, tmp_path, signal.SIGTERM)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    hint = {"garage_exp.loop": "; rerun the same command to go on where it stopped",
            "garage_exp": "; rerun the same command with resume=true to finish the sweep"}.get(prog, "")
    assert r.returncode == 143, r.stderr[-3000:]
    assert lines == [f"{prog}: terminated (SIGTERM){hint}"], r.stderr[-3000:]  # that line and nothing else


def test_ctrl_c_is_one_line_and_exit_130(tmp_path):
    """Ctrl-C (SIGINT) the same way, here for an argparse command (the Hydra ones: test_reliability_sweeps)."""
    r = signalled("garage_exp.plan", tmp_path, signal.SIGINT)
    assert (r.returncode, r.stderr) == (130, "garage_exp.plan: interrupted\n")
