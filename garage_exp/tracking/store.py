"""The default sqlite MLflow store: created or opened under a file lock, and a broken one named in one line.

MLflow creates a fresh sqlite store's schema (dozens of alembic migrations) in the first process that opens
it, without a lock: two sweeps started together on a fresh store both migrate, both crash ("table
_alembic_tmp_experiments already exists"), and the store is left half-migrated for every later client. Here the
first open of a store in a process holds `<store>.lock` (an flock, released when the process dies), so one
process creates the schema and the others wait for it and find it done.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE

# stores this process has opened (MLflow caches the store object per URI)
_OPENED: dict[str, bool] = STATE.cache("tracking.store.opened", "process")


def sqlite_path(uri: str) -> Path | None:
    """The database file of a sqlite:/// URI, None for any other store."""
    if not uri.startswith("sqlite:///"):
        return None
    return Path(uri[len("sqlite:///"):].split("?", 1)[0])


def open_store(uri: str, make):
    """`make()` (which creates the MLflow client, and with it the store) under the store's lock the first
    time this process opens a sqlite store; a store MLflow cannot use raises GarageError naming it."""
    path = sqlite_path(uri)
    if path is None or uri in _OPENED:
        return make()
    from filelock import FileLock

    path.parent.mkdir(parents=True, exist_ok=True)
    lock = FileLock(f"{path}.lock")
    try:
        lock.acquire()
    except OSError:  # a read-only place: nobody can create a schema there either
        lock = None
    try:
        try:
            client = make()
        except Exception as exc:  # noqa: BLE001 - MlflowException, sqlalchemy's errors: diagnosed below
            problem = diagnose(path, exc)
            if problem is None:
                raise
            raise GarageError(problem, str(path)) from None
    finally:
        if lock is not None:
            lock.release()
    _OPENED[uri] = True
    return client


def runs_in(path: Path) -> int | None:
    """How many runs the store holds (None when it has no readable runs table)."""
    try:
        with sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5) as con:
            return int(con.execute("select count(*) from runs").fetchone()[0])
    except sqlite3.Error:
        return None


def diagnose(path: Path, exc: BaseException) -> str | None:
    """One line for a store MLflow cannot open (half-migrated, out of date, not a database), saying how to
    recover; None for other errors."""
    text = str(exc)
    broken = ("out-of-date database schema", "already exists", "Online migration", "no such table",
              "no such column", "duplicate column", "file is not a database", "malformed")
    if not any(b in text for b in broken):
        return None
    first = text.strip().splitlines()[0] if text.strip() else type(exc).__name__
    if "(found version" in first:  # MLflow's own sentence is long: keep the versions
        first = "schema " + first[first.index("(found version") + 1:].split(")")[0]
    elif len(first) > 160:
        first = first[:157] + "..."
    if "file is not a database" in text:
        return f"not an MLflow sqlite store ({first}); move it away or set tracking.uri to another store"
    runs = runs_in(path)
    if not runs:
        return (f"broken MLflow store ({first}); it holds no runs: delete it (rm {path}) and rerun "
                "(a store is created under a lock now, so concurrent sweeps cannot break it again)")
    return (f"MLflow store cannot be opened ({first}); it holds {runs} runs: back it up (cp {path} "
            f"{path}.bak), then run `mlflow db upgrade sqlite:///{path}`")


def main(argv: list[str] | None = None) -> int:
    """`python -m garage_exp.tracking.store PATH`: create the sqlite store at PATH (under its lock) or check that MLflow
    can open it; `make ui` runs it first, so a broken store is one line (exit 2, the one shell's:
    garage_exp.core.shell) instead of the UI's traceback."""
    import argparse

    from garage_exp.core import shell

    def run(args) -> int:
        import mlflow

        uri = f"sqlite:///{args.path.absolute()}"
        open_store(uri, lambda: mlflow.MlflowClient(uri))
        return 0

    ap = argparse.ArgumentParser(prog="python -m garage_exp.tracking.store", description=main.__doc__.splitlines()[0])
    ap.add_argument("path", type=Path, metavar="PATH_TO_SQLITE_STORE")
    return shell.Command("garage_exp.tracking.store").run_args(ap, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
