"""The mutation score of `make mutation`, per module and in total, from `mutmut results --all true`.

Usage: python scripts/mutation_score.py [MUTANT_PATTERN ...] (the patterns `mutmut run` was given; none: all).
A mutant counts as detected when a test failed on it (killed), it hung (timeout) or crashed the interpreter
(segfault); "survived" and "no tests" count against the score; mutants mutmut skipped or did not check are
left out. Exit 0 always: the score is a measure, read it in docs/testing.md.
"""

from __future__ import annotations

import fnmatch
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

DETECTED = {"killed", "timeout", "segfault", "caught by type check"}
LEFT_OUT = {"skipped", "not checked"}


def results() -> list[tuple[str, str]]:
    mutmut = Path(sys.executable).with_name("mutmut")
    out = subprocess.run([str(mutmut), "results", "--all", "true"], capture_output=True, text=True, check=True).stdout
    pairs = []
    for line in out.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep and "__mutmut_" in name:
            pairs.append((name, status))
    return pairs


def module_of(name: str) -> str:
    return name.split(".x_")[0].split(".x\u01c1")[0]


def main(patterns: list[str]) -> int:
    chosen = [(n, s) for n, s in results() if not patterns or any(fnmatch.fnmatch(n, p) for p in patterns)]
    by_module: dict[str, Counter] = defaultdict(Counter)
    for name, status in chosen:
        by_module[module_of(name)][status] += 1
    total = Counter()
    print(f"{'module':34s} {'mutants':>7s} {'detected':>8s} {'survived':>8s} {'no tests':>8s} {'score':>6s}")
    for module, counts in sorted(by_module.items()):
        total.update(counts)
        _row(module, counts)
    _row("total", total)
    survivors = [n for n, s in chosen if s in ("survived", "no tests")]
    print(f"\n{len(survivors)} surviving mutants (`mutmut show NAME` for the diff):")
    for name in survivors:
        print(f"  {name}")
    return 0


def _row(label: str, counts: Counter) -> None:
    counted = sum(v for k, v in counts.items() if k not in LEFT_OUT)
    detected = sum(counts[k] for k in DETECTED)
    score = 100.0 * detected / counted if counted else float("nan")
    print(f"{label:34s} {counted:7d} {detected:8d} {counts['survived']:8d} {counts['no tests']:8d} {score:5.1f}%")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
