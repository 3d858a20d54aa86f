"""Issue 47, item 3: every `python -m garage_exp.loop` command docs/loop.md shows runs as written, at the small
setting the page documents for it: `estimate=true` (every step the loop would run is checked as its own command
checks it, the frame budget against the space's frame counts, then the estimate, with nothing written) in a
scratch `dir`. A command whose steps would be refused, or whose frame budget its cap of trials may not reach,
fails here rather than minutes into a reader's run; an estimate that writes a file (item 10) fails here too.

The steps' checks are the real ones; a check whose inputs another command already passed (the same space, plans,
fixed overrides, models or protocol: the page's commands mostly share the shipped config's) is not repeated, to
keep the file's time small."""

from __future__ import annotations

import re
import shlex

import pytest
from conftest import ROOT, run_in_process

# What distinguishes one search of a loop from another of the same space: its own settings and where it writes.
PER_STUDY = ("search.study=", "search.seed=", "search.sampler=", "search.trials=", "search.frames=",
             "search.startup=", "search.storage=", "hydra.sweep.dir=")


def loop_commands() -> list[list[str]]:
    """The arguments of each `python -m garage_exp.loop` command of docs/loop.md (code blocks and inline code,
    comments dropped), each once."""
    text = (ROOT / "docs" / "loop.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S)
    lines = [ln for block in blocks for ln in block.replace("\\\n", " ").splitlines()]
    lines += re.findall(r"`(python -m garage_exp\.loop\b[^`]*)`", text)
    commands = []
    for line in lines:
        words = shlex.split(line, comments=True)
        if words[:3] == ["python", "-m", "garage_exp.loop"] and words[3:] not in commands:
            commands.append(words[3:])
    return commands


def test_the_page_has_its_commands():
    commands = loop_commands()
    assert [] in commands and ["estimate=true"] in commands and ["--config-name", "loop_gpu"] in commands
    assert sum("trials=2" in c for c in commands) == 2  # the two tiny loops, end to end


@pytest.fixture(scope="module")
def once():
    """Each distinct step check (and step composition) once for the module: (kind, its inputs) -> its result."""
    return {}


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """One working dir for every command (so that their steps' inputs compare equal), empty after each."""
    return tmp_path_factory.mktemp("loop_docs")


@pytest.mark.parametrize("args", loop_commands(), ids=lambda a: " ".join(a) or "(defaults)")
def test_a_loop_command_of_the_docs_checks_and_estimates(args, work, monkeypatch, once):
    from garage_exp.loop import check
    from garage_exp.loop.app import cli

    search, sweep, compose = check._search, check._sweep, check._compose

    def memo_compose(loader, overrides):
        key = ("compose", tuple(overrides))
        if key not in once:
            once[key] = compose(loader, overrides)
        return once[key]

    def memo_search(overrides):
        key = ("search", tuple(o for o in overrides if not o.startswith(PER_STUDY)))
        if key in once:
            check._search_settings(overrides)  # its own settings (sampler, cap, budget) are still checked
        else:
            once[key] = search(overrides)
        return once[key]

    def memo_sweep(overrides):
        key = ("sweep", tuple(o for o in overrides if not o.startswith("hydra.sweep.dir=")))
        if key not in once:
            once[key] = sweep(overrides)

    monkeypatch.setattr(check, "_search", memo_search)
    monkeypatch.setattr(check, "_sweep", memo_sweep)
    monkeypatch.setattr(check, "_compose", memo_compose)
    # the page's own dir (/tmp/rounds_e2e) or the config's (under the project's outputs/) becomes a scratch one
    given = [a for a in args if not a.startswith("dir=")]
    r = run_in_process([*given, f"dir={work / 'loop'}", "estimate=true"], work, entry=cli)
    assert r.returncode == 0, r.stderr[-3000:]
    assert re.search(r"garage_exp\.loop: estimate: .*total [\d.]+ h", r.stdout), r.stdout[-3000:]
    assert re.search(r"garage_exp\.loop: power: .* \d+ held-out scenarios per detector detect 20 % fewer failures",
                     r.stdout), r.stdout[-3000:]  # the power estimate, from the config's pilot failure rate
    assert list(work.rglob("*")) == []  # an estimate writes nothing (item 10)
