"""The README's commands run as written: every `python -m garage_exp ...` line of its code blocks runs through
the real command line, each job's preflight building its whole scene (placements checked against their paths),
with only the frames (rendering, detection) left out. A command that drifts from the code (a renamed key, a
level that went away, a distance the schema now refuses) fails here instead of in a newcomer's first five
minutes."""

from __future__ import annotations

import re
import shlex

import pytest
from conftest import ROOT, run_app

PLACEHOLDERS = ("...", "/abs/path", "my_conf", "my_plan", "night")  # stand for the reader's own files


def readme_commands() -> list[list[str]]:
    """The argument lists of the README's `python -m garage_exp` commands (continuation lines joined, comments
    dropped), except those naming the reader's own files; a command the README shows twice (the bare one) once."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words[:3] == ["python", "-m", "garage_exp"] and not any(p in line for p in PLACEHOLDERS) \
                    and words[3:] not in commands:
                commands.append(words[3:])
    return commands


def checked(args: list[str]) -> list[str]:
    """The command as checked here: a search asks for two trials; a launcher's jobs run in processes of their own,
    where no frame loop is left out, so they are plan-only (dry_run=true)."""
    args = [a for a in args if not a.startswith("search.trials=")]
    if "hydra/sweeper=search" in args:
        args.append("search.trials=2")
    if any(a.startswith("hydra/launcher=") for a in args):
        args.append("dry_run=true")
    return args


@pytest.fixture
def built(monkeypatch) -> list:
    """The jobs' prepared scenes: each job stops after its preflight built its scene and its MLflow run opened."""
    seen = []

    def run_frames(prepared, out, run):
        seen.append(prepared)
        from garage_exp.results.summary import JobSummary

        return JobSummary(difficulty=0.5, frames=0, fair_frames=0)  # a search prunes such a trial

    monkeypatch.setattr("garage_exp.run.frames.run_frames", run_frames)
    return seen


def test_the_readme_has_commands_to_check():
    commands = readme_commands()
    assert len(commands) >= 10 and [] in commands  # the bare `python -m garage_exp` too
    assert any("hydra/sweeper=search" in c for c in commands)


@pytest.mark.parametrize("args", readme_commands(), ids=lambda a: " ".join(a) or "(defaults)")
def test_a_readme_command_runs_as_written(args, tmp_path, built):
    extra = [f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"]
    if "hydra/sweeper=search" in args:
        extra.append(f"search.storage=sqlite:///{tmp_path}/optuna.db")
    r = run_app([*checked(args), *extra], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    if "--cfg" in args:
        assert "case:" in r.stdout and "light:" in r.stdout
    elif "dry_run=true" not in checked(args):
        assert built and all(p.scene is not None and p.setup.shots for p in built)
