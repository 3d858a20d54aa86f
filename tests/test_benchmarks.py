"""The benchmarks (issue 32, item 6): grouped by kind, each one's arguments parse, results are small Markdown
pages without machine paths, and `make` names every benchmark in exactly one target. That the package never
imports a benchmark is an import contract (pyproject.toml, `lint-imports`)."""

from __future__ import annotations

import os
import re
import runpy
import sys

import pytest

from garage_exp.core.paths import PROJECT_ROOT

BENCH = PROJECT_ROOT / "benchmarks"
GROUPS = ("performance", "studies", "figures")
MODULES = sorted(f"benchmarks.{g}.{p.stem}" for g in GROUPS for p in (BENCH / g).glob("*.py") if p.stem != "__init__")


def test_every_benchmark_is_in_a_group():
    loose = sorted(p.name for p in BENCH.glob("*.py"))
    assert loose == ["__init__.py", "common.py", "jobkit.py"]  # only the shared helpers at the top
    assert len(MODULES) >= 19


@pytest.mark.parametrize("module", MODULES)
def test_each_benchmark_parses_its_arguments(module, monkeypatch, capsys):
    """`--help` runs the module as `python -m` does (its imports, its parser) and does nothing else."""
    monkeypatch.setattr(sys, "argv", [module, "--help"])
    monkeypatch.setattr(sys, "path", list(sys.path))
    monkeypatch.setattr(os, "environ", dict(os.environ))
    with pytest.raises(SystemExit) as stop:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    assert stop.value.code == 0
    assert capsys.readouterr().out.startswith("usage:")


def test_results_are_small_markdown_pages_without_machine_paths():
    files = sorted((BENCH / "results").iterdir())
    assert files and all(f.suffix == ".md" for f in files)
    for f in files:
        text = f.read_text()
        assert text.startswith("# "), f.name
        assert f.stat().st_size < 32_000, f"{f.name}: summarise, do not keep raw records"
        assert not re.search(r"(/work/|/home/|/tmp/|/Users/)", text), f.name


def test_make_runs_the_quick_benchmarks_and_names_the_others():
    make = (PROJECT_ROOT / "Makefile").read_text()
    named = {}
    for target in ("BENCH_QUICK", "BENCH_LONG", "BENCH_CLUSTER", "BENCH_GPU"):
        line = re.search(rf"^{target} := (.*)$", make, re.M)
        assert line, target
        for name in line.group(1).split():
            named.setdefault(f"benchmarks.{name}", []).append(target)
    measured = {m for m in MODULES if ".figures." not in m and not m.endswith(".before")}  # before needs --before
    assert set(named) == measured and all(len(v) == 1 for v in named.values())
    assert named["benchmarks.performance.ray_nodes"] == ["BENCH_CLUSTER"]
    assert named["benchmarks.performance.gpu"] == ["BENCH_GPU"]


def test_several_workers_are_counted_while_all_are_warm():
    """oneshot's `--workers`: the scenarios told after every worker's warm-up and before any stopped, in the order
    they ended, and the CPU of all of them per scenario each told after its warm-up."""
    from benchmarks.performance.oneshot import merge, rate

    one = {"code": 0, "epoch": 100.0, "ends": [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], "told": ["COMPLETE"] * 6,
           "cpu": [(1.0, 0.1), (3.0, 0.2)], "total": 7.0, "plans": [0, 1], "complete": 9, "trials": 12, "rejected": 3}
    two = {"code": 0, "epoch": 102.5, "ends": [0.5, 1.5, 2.0, 2.5, 4.5], "told": ["COMPLETE", "PRUNED"] * 2 + ["COMPLETE"],
           "cpu": [(1.0, 0.0), (2.0, 0.1)], "total": 5.0, "plans": [0, 1], "complete": 9, "trials": 12, "rejected": 3}
    both = merge([one, two], warmup=2)
    # warm from max(102, 104) = 104 to min(106, 107) = 106: one's 104, 105, 106 and two's 104, 104.5, 105
    assert both["ends"] == [104.0, 104.0, 104.5, 105.0, 105.0, 106.0]
    assert both["told"] == ["COMPLETE", "PRUNED", "COMPLETE", "COMPLETE", "PRUNED", "COMPLETE"]
    assert rate(both["ends"], both["window_warmup"]) == (2.5, 5)  # 5 told after the window's first, in 2 s
    assert both["cpu_per_scenario"] == pytest.approx(((2.0 + 1.0) / 7, (0.1 + 0.1) / 7))


def test_a_side_by_side_pair_gives_each_sides_rendered_rate_and_cpu_and_their_ratios():
    """oneshot's `--side-by-side`: a pair's sides are rated on what each rendered after its warm-up (told
    COMPLETE), per second of its own clock and per CPU second of its search process, and this checkout's ratios
    are to the other's."""
    from benchmarks.performance.oneshot import pair_row

    old = {"ends": [1.0, 2.0, 3.0, 4.0, 5.0], "told": ["COMPLETE", "PRUNED", "COMPLETE", "COMPLETE", "PRUNED"],
           "cpu": [(1.0, 0.1), (3.0, 0.2)]}
    new = {"ends": [1.0, 1.5, 2.5, 3.0, 3.5], "told": ["PRUNED", "COMPLETE", "COMPLETE", "COMPLETE", "COMPLETE"],
           "cpu": [(2.0, 0.0), (4.5, 0.1)]}
    row = pair_row(old, new, warmup=2)
    # old: 2 rendered after its 2nd end (at 3, 4) in 3 s, 2 CPU s; new: 3 rendered (2.5, 3, 3.5) in 2 s, 2.5 CPU s
    assert (row["before_rendered_per_s"], row["rendered_per_s"]) == (pytest.approx(0.667, abs=1e-3), 1.5)
    assert (row["before_cpu"], row["cpu"]) == (1.0, pytest.approx(0.833, abs=1e-3))
    assert row["rate_ratio"] == pytest.approx(2.25, abs=1e-3) and row["cpu_ratio"] == pytest.approx(0.833, abs=1e-3)


def test_each_archive_cells_page_keeps_its_searches_in_a_dir_of_its_own(tmp_path):
    """archive_cells resumes a study of the same sampler and seed found in its dir (an interrupted run goes on):
    by default that dir is the page's own, so a variant's run never continues another page's searches; `--out`
    still names any dir."""
    from benchmarks.common import ROOT
    from benchmarks.studies.archive_cells import out_dir

    assert out_dir("", "archive_cells_wide_iso") == ROOT / "outputs" / "benchmarks" / "archive_cells_wide_iso"
    assert out_dir("", "archive_cells") != out_dir("", "archive_cells_wide")
    assert out_dir(str(tmp_path), "archive_cells") == tmp_path


def test_oneshot_stages_reads_threads_and_tables_each_runs_stages():
    """oneshot_stages: this process's threads' CPU seconds from /proc (the main thread's named as the process),
    and a table with a stage a row, a run a column, a stage a checkout lacks shown as '-'."""
    from benchmarks.performance import oneshot_stages as st

    sum(i * i for i in range(200_000))  # some CPU for the main thread
    threads = st.thread_cpu()
    assert threads and all(v >= 0 for v in threads.values()) and max(threads.values()) > 0
    run = {"stages": {"a draw's requirement check": [0.9, 20], "the scene change": [1.5, 10]}, "trials": 30,
           "complete": 10, "rejected": 8, "told_timed": 12, "wall_timed": 6.5, "threads": {"python": 5.0},
           "missing": ["ground truth"]}
    lines = st.table([("`aaa`", run), ("`bbb`", {**run, "threads": {"python": 4.0, "llvmpipe": 1.0}})])
    assert lines[0] == "| stage (ms a call; calls) | `aaa` | `bbb` |"
    rows = {line.split(" | ")[0].lstrip("| "): line for line in lines[2:]}
    assert rows["a draw's requirement check"].endswith("| 45.0; 20 | 45.0; 20 |")
    assert rows["the scene change"].endswith("| 150.0; 10 | 150.0; 10 |")
    assert rows["ground truth"].endswith("| - | - |")
    assert rows["trials (complete, rejected)"].endswith("| 30 (10, 8) | 30 (10, 8) |")
    assert rows["thread llvmpipe, CPU s"].endswith("| 0.00 | 1.00 |")
    assert len(rows) == len(st.STAGES) + 4
