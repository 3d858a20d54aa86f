"""README facts pinned to the code, so that the README cannot drift silently: size limits, the bad-input
corpus, the factor table's levels against conf/."""

from __future__ import annotations

import re

import yaml
from conftest import ROOT

from garage_exp.plan import load

README = (ROOT / "README.md").read_text()


def test_plan_limits_in_the_readme_are_the_codes():
    assert f"at most {load.MAX_CELLS_PER_SIDE} cells a side" in README
    assert load.MAX_FILE_BYTES % 1_000_000 == 0
    assert f"files up to {load.MAX_FILE_BYTES // 1_000_000} MB" in README


def test_bad_input_corpus_size_in_the_readme_is_the_corpus():
    corpus = yaml.safe_load((ROOT / "tests" / "bad_inputs" / "cases.yaml").read_text())
    said = re.search(r"Bad input \((\d+) malformed", README)
    assert said and int(said.group(1)) == len(corpus)


def factor_table() -> dict[str, list[str]]:
    """The README's table of config groups: group -> the levels it names (column 2's backticked words)."""
    section = README.split("| group | levels | what it sets |", 1)[1].split("\n\n", 1)[0]
    rows = {}
    for line in section.splitlines()[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        groups = re.findall(r"`([^`]+)`", cells[0])
        levels = re.findall(r"`([^`]+)`", re.sub(r"\([^)]*\)", "", cells[1]))  # not the notes in brackets
        if len(groups) == 1:
            rows[groups[0]] = levels
        else:  # "`renderer`, `tracking` | `sapien`, `mlflow`": one level each
            rows.update({g: [lv] for g, lv in zip(groups, levels, strict=True)})
    return rows


def test_factor_table_levels_are_the_config_files():
    table = factor_table()
    groups = {p.name for p in (ROOT / "conf").iterdir() if p.is_dir() and p.name not in ("hydra", "experiment")}
    assert set(table) == groups
    for group, levels in table.items():
        files = {p.stem for p in (ROOT / "conf" / group).glob("*.yaml")}
        assert set(levels) == files, group
