"""The small files a sweep keeps in its directory for its workers: the parent run's id and the finished runs a
resumed sweep skipped."""

from __future__ import annotations

from pathlib import Path

PARENT_FILE = "mlflow_parent_run_id"
RESUMED_FILE = "mlflow_resumed_run_ids"


def write_parent(sweep_dir: str | Path, run_id: str) -> None:
    path = Path(sweep_dir)
    path.mkdir(parents=True, exist_ok=True)
    (path / PARENT_FILE).write_text(run_id)


def read_parent(sweep_dir: str | Path) -> str | None:
    path = Path(sweep_dir) / PARENT_FILE
    return path.read_text().strip() if path.is_file() else None


def add_resumed(sweep_dir: str | Path, run_id: str) -> None:
    """Record a finished run that a resumed sweep skipped (one line per run; appends are atomic enough for
    short lines from several workers)."""
    with open(Path(sweep_dir) / RESUMED_FILE, "a") as fh:
        fh.write(run_id + "\n")


def read_resumed(sweep_dir: str | Path) -> list[str]:
    path = Path(sweep_dir) / RESUMED_FILE
    return sorted(set(path.read_text().split())) if path.is_file() else []


def clear_resumed(sweep_dir: str | Path) -> None:
    """A sweep starting in a used sweep dir must not count the skips of an earlier one."""
    (Path(sweep_dir) / RESUMED_FILE).unlink(missing_ok=True)
