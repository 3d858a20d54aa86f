"""The commands of docs/search.md and docs/openscenario.md run as written (issue 47): every command of their code
blocks is listed in COVERED with the test that runs it, here or in another file, or with why the suite cannot
(a file not in the repository, an hour-long benchmark); a command added to those pages without a line there fails
`test_every_command_of_the_pages_is_covered`. The commands run here go through the real command line, as
tests/test_readme_commands.py runs the README's: each job's preflight builds its whole scene and writes what it
writes before its frames (its OpenSCENARIO export), with only the frames (rendering, detection) left out; a search
asks for two trials (`search.trials=2`). The esmini command runs as written, in a job's folder laid out as the
project's (`outputs/runs/<date>/<time>/openscenario`, `shared/` beside the project)."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest
from conftest import ROOT, require, run_app, run_module
from test_readme_commands import built  # noqa: F401  (each job stops after its preflight: its prepared jobs)

PAGES = ("search.md", "openscenario.md")

# Each command of the pages' code blocks (continuation lines joined, a block's `cd` and the command after it one
# script) -> the test that runs it, or "not run: why".
COVERED = {
    "python -m garage_exp -m hydra/sweeper=search search.trials=80 plan=research case=1": "test_a_search_command_runs",
    "python -m garage_exp -m hydra/sweeper=search search.sampler=archive search.trials=30":
        "test_a_search_command_runs",
    "python -m benchmarks.studies.archive_cells --trials 30 --seeds 0,1,2 --workers 2":
        "not run: a benchmark of about an hour that rewrites benchmarks/results/archive_cells.md; its arguments parse "
        "in tests/test_benchmarks.py, its searches are the archive search above",
    "python -m garage_exp -m hydra/sweeper=search search.sampler=archive search.trials=2000 search.runs=per_search":
        "not run: 2,000 one-shot scenarios (minutes); the same search at two trials, one MLflow run and kept garages "
        "is tests/test_oneshot.py's end-to-end search, and its arguments are benchmarks/performance/oneshot.py's",
    "python -m garage_exp.search.grade --storage sqlite:///outputs/search/optuna.db --study <suite study>":
        "not run: <suite study> is the reader's own suite as written; the command runs on a suite study of its own in "
        "tests/test_grade.py (test_the_fresh_draws_run_through_the_real_search_as_enqueued)",
    "python -m garage_exp -m hydra/sweeper=search space=wide search.trials=2": "test_the_wide_space_search_runs",
    "python -m garage_exp -m hydra/sweeper=search space=wide search.mode=suite search.suite.levels=5":
        "not run: the graded suite measured in docs/search.md (about 40 minutes a detector); a suite with levels and "
        "its fresh draws through the real search is tests/test_grade.py "
        "(test_the_fresh_draws_run_through_the_real_search_as_enqueued), the wide space's search above",
    "python -m garage_exp.search.grade --storage sqlite:///DIR/optuna.db --study suite-NAME":
        "not run: DIR and NAME are the measured suite's (the command above); the same command on a suite study of "
        "its own is tests/test_grade.py (test_the_fresh_draws_run_through_the_real_search_as_enqueued)",
    "python -m benchmarks.studies.archive_cells --space wide --trials 1500":
        "not run: a benchmark of about 75 minutes of both cores that rewrites benchmarks/results/archive_cells_wide.md; "
        "its arguments parse in tests/test_benchmarks.py, its searches are the wide space's search above",
    "python -m benchmarks.studies.archive_cells --space wide --trials 60":
        "not run: a benchmark of minutes that rewrites benchmarks/results/archive_cells_wide_pilot.md; its arguments "
        "parse in tests/test_benchmarks.py, its searches are the wide space's search above",
    "python -m garage_exp case=cpnco export.openscenario=true": "test_an_export_command_writes_its_files",
    "python -m garage_exp case=crossing export.openscenario=true export.openscenario_version=1.0":
        "test_an_export_command_writes_its_files",
    "cd outputs/runs/<date>/<time>/openscenario": "test_the_documented_esmini_command_plays_an_export",
    "python -m garage_exp.scenario.import scenario.xosc --name mine": "test_the_import_commands_run_as_written",
    "python -m garage_exp --config-dir . case=mine ego.speed=10": "test_the_import_commands_run_as_written",
    "python -m garage_exp.scenario.import NCAP_AEB_VRU_CPNCO_2023.xosc --name ncap_cpnco":
        "not run: Vector's NCAP file is not in the repository (MPL-2.0, not copied); what it needs of the importer "
        "(catalogs, a SynchronizeAction, --param) is tested on files of the same shape in test_openscenario.py and "
        "test_xosc_import.py",
}


def page_commands(page: str) -> list[str]:
    """The commands of a page's ```bash blocks: continuation lines joined, comments dropped; a `cd` line and the
    command after it one script."""
    found = []
    for block in re.findall(r"```bash\n(.*?)```", (ROOT / "docs" / page).read_text(), re.S):
        lines = [ln.split(" #")[0].strip() for ln in block.replace("\\\n", " ").splitlines() if ln.strip()]
        k = 0
        while k < len(lines):
            if lines[k].startswith("cd ") and k + 1 < len(lines):
                found.append(f"{lines[k]}\n{lines[k + 1]}")
                k += 2
            else:
                found.append(lines[k])
                k += 1
    return found


def command(page: str, start: str) -> str:
    """The page's command that starts with `start` (as COVERED names it)."""
    (found,) = [c for c in page_commands(page) if " ".join(c.split()).startswith(start)]
    return found


def test_every_command_of_the_pages_is_covered():
    for page in PAGES:
        for text in page_commands(page):
            flat = " ".join(text.split())
            keys = [k for k in COVERED if flat.startswith(k)]
            assert len(keys) == 1, f"docs/{page}: {flat!r} is run by no test (add it to COVERED)"
            how = COVERED[keys[0]]
            assert how.startswith("not run: ") or how in globals() or "::" in how, how


def argv(text: str, prefix: str = "python -m garage_exp") -> list[str]:
    import shlex

    words = shlex.split(text)
    assert " ".join(words[:len(prefix.split())]) == prefix, text
    return words[len(prefix.split()):]


@pytest.mark.parametrize("start", [k for k, v in COVERED.items() if v == "test_a_search_command_runs"])
def test_a_search_command_runs(start, tmp_path, built):
    args = [a for a in argv(command("search.md", start)) if not a.startswith("search.trials=")]
    r = run_app([*args, "search.trials=2", f"search.storage=sqlite:///{tmp_path}/optuna.db",
                 f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert len(built) == 2 and all(p.scene is not None and p.setup.shots for p in built)
    assert "this worker ran 2" in r.stdout


def test_the_wide_space_search_runs(tmp_path, built):
    """The wide space's search as written (two trials, frames left out): its 31 factors checked, each draw checked
    against its requirements before its job, generated garages and any straight run; the summary says how many draws
    the requirements kept."""
    args = argv(command("search.md", "python -m garage_exp -m hydra/sweeper=search space=wide search.trials=2"))
    r = run_app([*args, "search.sampler=random", f"search.storage=sqlite:///{tmp_path}/optuna.db",
                 f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    # one-shot; a draw whose occluder stands in the ego at every site is pruned before its job (infeasible)
    assert 1 <= len(built) <= 2 and all(p.scene is not None and len(p.setup.shots) == 1 for p in built)
    assert all(p.plan_path.name.startswith("generated") or "generated" in str(p.plan_path) for p in built), \
        [str(p.plan_path) for p in built]
    assert "this worker ran 2" in r.stdout and "requirements:" in r.stdout and "draws accepted" in r.stdout


def export_job(page_command: str, tmp_path) -> None:
    """A documented export command as a job (frames left out), in tmp_path/run (conftest.run_app's run dir)."""
    r = run_app([*argv(page_command), f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]


@pytest.mark.parametrize("start, version", [("python -m garage_exp case=cpnco", "OpenSCENARIO_1_2"),
                                            ("python -m garage_exp case=crossing", "OpenSCENARIO_1_0")])
def test_an_export_command_writes_its_files(start, version, tmp_path, built):
    from garage_exp.openscenario.asam import validate

    export_job(command("openscenario.md", start), tmp_path)
    assert validate(tmp_path / "run" / "openscenario" / "scenario.xosc").startswith(version)
    assert validate(tmp_path / "run" / "openscenario" / "garage.xodr").startswith("opendrive")


def test_the_documented_esmini_command_plays_an_export(tmp_path, built):
    """The page's esmini block as written, in the folder of a `case=cpnco export.openscenario=true` job laid out as
    the project lays it out (conf/config.yaml's run dir), with `shared/` beside the project: esmini is found by the
    block's relative path, writes log.csv, and its own log goes where the block says, beside the scenario; no
    log.txt anywhere (issue 47, item 5: the block had one `..` too few and left log.txt in the current folder)."""
    from tools.esmini import esmini_path

    require("esmini")
    assert "dir: ${garage_root:}/outputs/runs/${now:%Y-%m-%d}/${now:%H-%M-%S}" in (ROOT / "conf" / "config.yaml").read_text()
    script = command("openscenario.md", "cd outputs/runs/<date>/<time>/openscenario")
    work = tmp_path / "work"
    project, tools = work / "project", work / "shared" / "tools" / "esmini"
    job = project / "outputs" / "runs" / "2026-12-05" / "23-00-00"
    tools.mkdir(parents=True)
    (tools / "esmini").symlink_to(esmini_path())
    export_job(command("openscenario.md", "python -m garage_exp case=cpnco"), tmp_path)
    shutil.copytree(tmp_path / "run" / "openscenario", job / "openscenario")  # where the job would have put it
    script = script.replace("<date>", "2026-12-05").replace("<time>", "23-00-00")
    done = subprocess.run(["bash", "-ec", script], cwd=project, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, (done.stdout + done.stderr)[-3000:]
    folder = job / "openscenario"
    rows = (folder / "log.csv").read_text().splitlines()
    assert len(rows) > 20 and "child" in (folder / "log.csv").read_text()
    assert (folder / "esmini.log").is_file()
    assert not list(work.rglob("log.txt")), list(work.rglob("log.txt"))


def test_the_import_commands_run_as_written(tmp_path, built):
    """`python -m garage_exp.scenario.import scenario.xosc --name mine` beside an export (its scenario.xosc and
    garage.xodr), then `python -m garage_exp --config-dir . case=mine ego.speed=10` in the same folder."""
    export_job(command("openscenario.md", "python -m garage_exp case=cpnco"), tmp_path)
    here = tmp_path / "here"
    shutil.copytree(tmp_path / "run" / "openscenario", here)
    imported = run_module("garage_exp.scenario.import",
                          argv(command("openscenario.md", "python -m garage_exp.scenario.import scenario.xosc"),
                               "python -m garage_exp.scenario.import"), here)
    assert imported.returncode == 0, imported.stderr[-3000:]
    assert (here / "case" / "mine.yaml").is_file()
    built.clear()
    r = run_app([*argv(command("openscenario.md", "python -m garage_exp --config-dir . case=mine")),
                 f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"], here)
    assert r.returncode == 0, r.stderr[-3000:]
    (prepared,) = built
    assert prepared.scene is not None and prepared.setup.shots
