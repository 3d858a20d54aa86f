"""What every benchmark shares without importing the project: where the checkout and the results are, the
environment of a benchmark's child process, and reading and writing a results page.

Results are Markdown pages in benchmarks/results/ (one format): a heading, what was run, then the benchmark's
own table; numbers a later run reads back (bench_gpu's --against) sit in one fenced ```json block.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent  # the checkout
RESULTS = ROOT / "benchmarks" / "results"


def child_env(code: str | Path | None = None, **extra: str) -> dict[str, str]:
    """The environment of a benchmark's child process (`python FILE --child ...`): no progress bars, offline,
    `code`'s garage_exp first (default: this checkout's) and this checkout's benchmarks package."""
    paths = [str(code or ROOT), str(ROOT)]
    return {**os.environ, "TQDM_DISABLE": "1", "YOLO_OFFLINE": "1", "PYTHONPATH": os.pathsep.join(paths), **extra}


def write_json_page(path: Path, title: str, data: dict) -> None:
    """A results page holding numbers that a later run reads back (read_json_page)."""
    path.write_text(f"# {title}\n\n```json\n{json.dumps(data, indent=1)}\n```\n")


def read_json_page(path: Path) -> dict:
    found = re.search(r"```json\n(.*?)\n```", path.read_text(), re.S)
    if found is None:
        raise ValueError(f"{path}: no ```json block")
    return json.loads(found.group(1))
