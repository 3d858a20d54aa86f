"""README and docs facts pinned to the code and the repository, so that neither can drift silently: the README's
length and links, the plan size limits and the shipped plans, the bad-input corpus, the factor table's levels
against conf/, the shipped cases and the pedestrian's heights, the search's samplers, the exit codes, and the
tests the docs name. Each check is cheap: files read, plans classified, nothing rendered. (`make test` also builds
the docs with `mkdocs build --strict`, which checks every link and anchor between the pages.)"""

from __future__ import annotations

import re
import unicodedata

import yaml
from conftest import ROOT

from garage_exp.plan import load

README = (ROOT / "README.md").read_text()
DOCS = ROOT / "docs"


def doc(name: str) -> str:
    return (DOCS / name).read_text()


def table_after(text: str, header: str) -> list[list[str]]:
    """The rows of the markdown table whose header line starts with `header`, as lists of stripped cells."""
    section = text.split(header, 1)[1].split("\n\n", 1)[0]
    return [[c.strip() for c in line.strip().strip("|").split("|")] for line in section.splitlines()[2:]]


def slug(heading: str) -> str:
    """The anchor Python-Markdown's toc gives a heading (the docs site's, and GitHub's for plain headings)."""
    text = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode()
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def test_readme_is_at_most_250_lines():
    assert len(README.splitlines()) <= 250


def test_every_relative_link_in_the_readme_resolves():
    links = re.findall(r"\]\(([^)\s]+)\)", README)
    relative = [t for t in links if not re.match(r"[a-z]+:", t)]
    assert relative, "the README links into the docs"
    for target in relative:
        path, _, anchor = target.partition("#")
        file = ROOT / path if path else ROOT / "README.md"
        assert file.is_file(), target
        if anchor and file.suffix == ".md":
            headings = re.findall(r"^#+ (.+)$", file.read_text(), re.M)
            assert anchor in {slug(h) for h in headings}, target


def test_plan_limits_in_the_docs_are_the_codes():
    plans = doc("plans.md")
    assert f"at most {load.MAX_CELLS_PER_SIDE} cells a side" in plans
    assert load.MAX_FILE_BYTES % 1_000_000 == 0
    assert f"files up to {load.MAX_FILE_BYTES // 1_000_000} MB" in plans


def test_shipped_plans_table_is_what_the_plans_are():
    from garage_exp.plan.classify import classify

    rows = table_after(doc("plans.md"), "| file | cells (rows x columns) |")
    files = {p.name for p in (ROOT / "plans").iterdir() if p.suffix in (".yaml", ".csv")}
    assert {r[0].strip("`") for r in rows} == files
    for name, cells, size, corners, tees, crosses, pillars, _ in rows:
        classified = classify(load.load_plan(ROOT / "plans" / name.strip("`")))
        m, n = classified.plan.shape
        width, depth = classified.plan.size
        lanes = [c.type for c in classified.all_cells() if c.kind == "lane"]
        said = (cells, size, int(corners), int(tees), int(crosses), int(pillars))
        assert said == (f"{m} x {n}", f"{width:.1f} x {depth:.1f}", lanes.count("corner"), lanes.count("t_junction"),
                        lanes.count("crossroads"), len(classified.pillars)), name


def test_bad_input_corpus_size_in_the_docs_is_the_corpus():
    corpus = yaml.safe_load((ROOT / "tests" / "bad_inputs" / "cases.yaml").read_text())
    said = re.findall(r"`tests/bad_inputs/cases.yaml` has (\d+) entries", doc("reliability.md"))
    assert said == [str(len(corpus))]
    for page in [README, *(p.read_text() for p in DOCS.glob("*.md"))]:  # the count is written once
        assert not re.search(r"\d+ (malformed|bad-input|corpus) ", page)


def factor_table() -> dict[str, list[str]]:
    """The docs' table of config groups: group -> the levels it names (column 2's backticked words)."""
    rows = {}
    for cells in table_after(doc("configuration.md"), "| group | levels | what it sets |"):
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


def test_shipped_cases_and_the_pedestrians_heights_are_the_case_files():
    scenarios = doc("scenarios.md")
    listed = re.findall(r"^- `([^`]+)` \(site `(\w+)`\)", scenarios, re.M)
    cases = {p.stem: yaml.safe_load(p.read_text()) for p in (ROOT / "conf" / "case").glob("*.yaml")}
    assert {name: site for name, site in listed} == {name: case["site"] for name, case in cases.items()}
    actors = cases["pedestrian"]["actors"]
    child, adult = actors["child"]["height"], actors["adult"]["height"]
    assert f"a child ({child:g} m)" in scenarios and f"an adult ({adult:g} m)" in scenarios
    results = doc("results.md")
    assert f"| adult {adult:g} m, 6 m |" in results and f"| child {child:g} m, 6 m |" in results


def test_samplers_in_the_docs_are_the_codes():
    from garage_exp.search.study import SAMPLERS

    settings = doc("search.md").split("- **Settings**", 1)[1].split("- **Hard but fair", 1)[0]
    sampler_text = settings.split("`sampler` (", 1)[1].split("`objective`", 1)[0]
    assert set(re.findall(r"`(\w+)`", sampler_text)) - {"grid_levels"} == set(SAMPLERS)


def test_exit_codes_in_the_readme_are_the_codes():
    try:
        from garage_exp.core import exits
    except ImportError:  # the package's layout before issue 20
        from garage_exp import cli_errors as exits

    codes = {int(c) for c in re.findall(r"^\| (\d+) \|", README.split("**Exit codes.**", 1)[1], re.M)}
    assert {exits.EXIT_INPUT, exits.EXIT_FAILED_JOBS} <= codes
    assert codes == {0, exits.EXIT_FAILED_JOBS, exits.EXIT_INPUT, 130, 143}  # 128 + SIGINT, 128 + SIGTERM


def test_tests_named_in_the_readme_and_docs_exist():
    defined = {m for p in (ROOT / "tests").glob("*.py")
               for m in re.findall(r"^(?:async )?def (test_\w+)", p.read_text(), re.M)}
    files = {p.stem for p in (ROOT / "tests").glob("test_*.py")}
    for page in [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]:
        named = set(re.findall(r"\b(test_\w+)", page.read_text()))
        named = {n for n in named if not n.endswith("_")}  # `test_plan_*`: a pattern, not a name
        assert named <= defined | files, (page.name, sorted(named - defined - files))


# the machine: one of docs/results.md's machines (the two cores a number was measured on)
PROVENANCE = re.compile(r"\*\*Measured:\*\* `[^`]+`.* · commit `[0-9a-f]{7}`.* · \d{4}-\d{2}-\d{2} · \[(Zen [345]|Xeon)\]\(")


def test_every_results_table_names_its_command_commit_date_and_machine():
    """A table without them is not a result: each table of the results and performance pages has a **Measured:**
    line between it and the heading or table before it (or says its provenance is unknown)."""
    for name in ("results.md", "performance.md"):
        lines, before, tables = doc(name).splitlines(), [], 0
        for i, line in enumerate(lines):
            if line.startswith("|") and not (i and lines[i - 1].startswith("|")):
                tables += 1
                text = "\n".join(before)
                assert PROVENANCE.search(text) or "provenance unknown" in text, (name, line)
                before = []
            elif line.startswith("#") or line.startswith("|"):
                before = []
            else:
                before.append(line)
        assert tables >= 10, name
