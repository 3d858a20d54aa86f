"""The suite hands the slowest files to the xdist workers first (tests/conftest.py, tests/file_seconds.json)."""

import json

from conftest import ROOT, file_order_key


def test_files_go_out_slowest_first_and_a_new_file_by_its_test_count():
    key = file_order_key({"tests/a.py": 100.0, "tests/b.py": 3.0}, {"tests/a.py": 2, "tests/b.py": 40, "tests/new.py": 9})
    assert sorted(["tests/b.py", "tests/new.py", "tests/a.py"], key=key) == ["tests/a.py", "tests/new.py", "tests/b.py"]


def test_the_table_names_files_that_exist():
    table = json.loads((ROOT / "tests" / "file_seconds.json").read_text())
    assert table and all((ROOT / name).is_file() for name in table), [n for n in table if not (ROOT / n).is_file()]
