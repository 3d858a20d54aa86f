"""A search worker kept on the CPUs it is given (`search.cpus`), with its renderer's threads and its detector's
process.

Two workers of one study on a 2-core machine (the same command started twice on one storage) each run a Python
thread, lavapipe's rasterising threads and a detector process. Left to the scheduler, the six wander over both
cores and each worker's threads evict the other's caches: two workers rendered 4.6-4.9 one-shot scenarios a
second on an Intel Xeon where each kept on its own core rendered 5.2-5.3 (docs/performance.md). `search.cpus=0`
and `search.cpus=1` keep them apart. Linux only (sched_setaffinity); elsewhere the setting is refused.
"""

from __future__ import annotations

import os
from pathlib import Path

from garage_exp.core.errors import GarageError

WHERE = "search.cpus"


def parse(value) -> set[int] | None:
    """The CPUs a setting names: None (not pinned), an int, or text such as "1", "0-3" or "0,2"; GarageError
    naming search.cpus for anything else or a CPU this process may not use."""
    if value is None or str(value).strip() in ("", "none", "null"):
        return None
    cpus: set[int] = set()
    try:
        for part in str(value).replace(" ", "").split(","):
            first, _, last = part.partition("-")
            low, high = int(first), int(last or first)
            if low < 0 or high < low:
                raise ValueError(part)
            cpus.update(range(low, high + 1))
    except ValueError:
        raise GarageError(f"{value!r} is not a CPU list (a CPU number, a range 0-1 or a list 0,2)", WHERE) from None
    if not hasattr(os, "sched_setaffinity"):
        raise GarageError("this system cannot keep a process on chosen CPUs (no sched_setaffinity)", WHERE)
    allowed = os.sched_getaffinity(0)
    if not cpus <= allowed:
        raise GarageError(f"CPU {min(cpus - allowed)} is not one this process may use "
                          f"({', '.join(map(str, sorted(allowed)))})", WHERE)
    return cpus


def pin(cpus: set[int] | None) -> list[int]:
    """Keep this process, each of its threads and every process it started (and their threads) on `cpus`;
    threads and processes made later inherit it. Returns the processes pinned (this one first)."""
    if not cpus:
        return []
    pids = [os.getpid(), *descendants(os.getpid())]
    for pid in pids:
        for task in _tasks(pid):
            try:
                os.sched_setaffinity(task, cpus)
            except (ProcessLookupError, PermissionError):  # a thread that ended meanwhile
                pass
    return pids


def descendants(pid: int) -> list[int]:
    """The processes `pid` started, and theirs, from /proc."""
    parents: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:  # ended meanwhile
            continue
        fields = text[text.rfind(")") + 2:].split()  # the name may hold spaces and parentheses
        parents.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        for child in parents.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _tasks(pid: int) -> list[int]:
    try:
        return [int(p.name) for p in Path(f"/proc/{pid}/task").iterdir()]
    except OSError:
        return [pid]
