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


# The search benchmarks' scenario and space (studies/search.py, studies/soak.py, performance/gpu.py): case 1 with a
# black target whose distance, yaw and the light a search varies.
SCENARIO = ["plan=research", "case=1", "palette.target_colours=[black]", "case.motion.start=12", "case.motion.end=10",
            "case.actors.target.clip=true"]  # a distance below the target's room (2.6 m) trimmed to it, as measured
SPACE = ["light.intensity=interval(0.1,1.0)", "case.actors.target.distance=interval(2.0,10.0)",
         "case.actors.target.yaw=interval(-90.0,90.0)"]
