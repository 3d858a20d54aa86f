"""Disk space: what a job will write (estimated before it starts, from measured sizes) and a full disk
recognised in any error, whichever library raised it."""

from __future__ import annotations

import errno
import shutil
from pathlib import Path

from garage_exp.core.errors import GarageError

MB = 1 << 20
# Measured at 640x480 (research, realistic and tiny plans): a render saved as PNG is 54-108 kB of its 921 kB
# raw pixels; plan maps 75-103 kB, confidence plots 47-94 kB, frames.csv ~120 bytes a row. The estimate
# rounds each up, so it errs on the safe side by about a factor of two.
PNG_PER_PIXEL = 0.4  # bytes per pixel of a saved frame
FIXED = 400_000  # a job's config copies, plan map, confidence plot, log, Hydra's files
ROW = 400  # frames.csv and the step metrics, per frame
STORE_FIXED = 200_000  # a run's params, tags and metrics in a sqlite store


def mb(n: float) -> str:
    return f"{n / MB:.1f} MB" if n < 10 * MB else f"{n / MB:.0f} MB"


def existing(path: Path) -> Path:
    """The path itself or its nearest existing ancestor (what a directory not yet made will live on)."""
    path = Path(path).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


class NotEnoughSpace(GarageError):
    """The free space cannot hold what is about to be written."""


def check_free(needs: list[tuple[Path, int]], what: str) -> None:
    """NotEnoughSpace (a GarageError) when the bytes to be written under each directory do not fit the free space of its
    filesystem (directories on one filesystem add up)."""
    per_fs: dict[int, list] = {}
    for directory, n in needs:
        if n <= 0:
            continue
        where = existing(directory)
        entry = per_fs.setdefault(where.stat().st_dev, [where, 0])
        entry[1] += n
    for where, need in per_fs.values():
        free = shutil.disk_usage(where).free
        if need > free:
            raise NotEnoughSpace(f"not enough free disk space: {what} will write about {mb(need)} on this "
                              f"filesystem and {mb(free)} is free; free some space, or write elsewhere "
                              "(hydra.sweep.dir=..., tracking.uri=...), or save fewer frames "
                              "(renderer.save_frames=key)", str(where))


def full_disk(exc: BaseException | None) -> str | None:
    """The path (or "" when unknown) where a write failed for want of space, if that is what `exc` (or any
    exception it was raised from) says; None otherwise. OSError ENOSPC/EDQUOT from Python's own writes,
    sqlite's "database or disk is full", and libraries that only keep the message."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return str(exc.filename or "")
        text = str(exc)
        if any(s in text for s in ("No space left on device", "database or disk is full", "Disk quota exceeded")):
            return ""
        exc = exc.__cause__ or exc.__context__
    return None
