"""Write tests/file_seconds.json from a pytest JUnit XML report: each test file's seconds (setup, call and
teardown summed), which tests/conftest.py uses to hand the slowest files to the xdist workers first.

    .venv/bin/python -m pytest -n auto --dist loadfile --junitxml=/tmp/suite.xml
    .venv/bin/python scripts/file_seconds.py /tmp/suite.xml

Why: `--dist loadfile` gives a worker a whole file at a time, in collection order; xdist's own reordering puts
the files with the most tests first, which left the two-test cluster file (100 s) for last, running alone while
the other worker idled. The longest-first order is the classic greedy schedule for two machines.
"""

import json
import sys
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

OUT = Path(__file__).resolve().parent.parent / "tests" / "file_seconds.json"


def file_seconds(report: Path) -> dict[str, float]:
    seconds: Counter = Counter()
    for case in ET.parse(report).iter("testcase"):
        parts = case.get("classname", "").split(".")
        if len(parts) >= 2 and parts[0] == "tests":
            seconds[f"tests/{parts[1]}.py"] += float(case.get("time", 0))
    return {name: round(s, 1) for name, s in sorted(seconds.items(), key=lambda kv: -kv[1])}


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: scripts/file_seconds.py REPORT.xml")
    OUT.write_text(json.dumps(file_seconds(Path(sys.argv[1])), indent=1) + "\n")
    print(f"wrote {OUT}")
