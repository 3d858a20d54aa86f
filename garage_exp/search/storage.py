"""The study's storage when it is a database server (PostgreSQL on a cluster): patient, and one lock for all.

A database restarts (an operator, a failover) for a few seconds; a search of hours should wait, not die. Every
storage call is retried while the database does not answer, for up to $GARAGE_EXP_STORAGE_WAIT seconds (180),
with one line when the wait starts and one when the database is back, as the tracking store does
(tracking.runs.retry); after that the search stops (SweepStopped: one line, exit 1, `resume=true` continues).

The workers of a study count its trials and ask for one as one step (search.loop), so the budget is exact: a
sqlite store locks a file beside it; a PostgreSQL store takes a session-level advisory lock, held by a
connection of its own (a lock ends with its session, so a worker that dies releases it).
"""

from __future__ import annotations

import contextlib
import hashlib
import re
import sys
import threading
import time

from optuna.storages import RDBStorage

from garage_exp.core.exits import SweepStopped, stopping, wait_seconds
from garage_exp.core.state import STATE

# What psycopg and SQLAlchemy say while the server is down, restarting or cut the connection.
DOWN = ("connection refused", "could not connect", "connection to server at", "server closed the connection",
        "terminating connection due to administrator command", "the database system is shutting down",
        "the database system is starting up", "the database system is in recovery mode", "connection is closed",
        "connection reset", "broken pipe", "ssl syscall error", "consuming input failed")


def storage_wait() -> float:
    """How long a call waits for a database that went away ($GARAGE_EXP_STORAGE_WAIT, seconds)."""
    return wait_seconds("GARAGE_EXP_STORAGE_WAIT")


def hidden(url: str) -> str:
    """The URL with its password hidden (it goes into log lines)."""
    return re.sub(r"(://[^:/@]+):[^@]*@", r"\1:***@", url)


def why_down(exc: BaseException) -> str | None:
    """What says the database did not answer (not a bad query), looked for along the exception's causes: its
    first line, or None."""
    seen = 0
    while exc is not None and seen < 8:
        text = f"{type(exc).__name__}: {exc}"
        if any(t in text.lower() for t in DOWN):
            return text.strip().splitlines()[0][:160]
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


def is_down(exc: BaseException) -> bool:
    return why_down(exc) is not None


def call(fn, url: str):
    """fn(), waiting for the database at `url` while it does not answer. Each call times its own wait: a wait
    that ended in another error must not shorten the next one."""
    since, k = None, 0
    while True:
        try:
            result = fn()
        except Exception as exc:  # noqa: BLE001 - only a database that is away is waited for
            why = why_down(exc)
            if why is None:
                raise
            now = time.monotonic()
            if since is None:
                since = now
                print(f"garage_exp: optuna storage {hidden(url)} not answering; retrying for up to "
                      f"{storage_wait():.0f} s (GARAGE_EXP_STORAGE_WAIT)", file=sys.stderr, flush=True)
            waited = now - since
            if stopping() or waited >= storage_wait():
                raise SweepStopped(f"the optuna storage {hidden(url)} did not answer for {waited:.0f} s ({why})",
                                   "start the database, then run the same command with resume=true") from None
            time.sleep(min(5.0, 0.25 * 2.0 ** min(k, 5), storage_wait() - waited + 0.01))
            k += 1
            continue
        if since is not None:
            print(f"garage_exp: optuna storage {hidden(url)} answers again after {time.monotonic() - since:.0f} s",
                  file=sys.stderr, flush=True)
        return result


class PatientStorage(RDBStorage):
    """Optuna's RDBStorage whose calls wait for a database that restarts (see `call`). Retrying a write whose
    commit reached the server just before the connection broke could repeat it; Optuna's own writes either
    fail as a whole (a transaction) or are idempotent (attributes, a state already set), the one exception
    being a new trial, which the trial loop fails as stale by its heartbeat."""


def _patient(name: str):
    method = getattr(RDBStorage, name)

    def wrapper(self, *args, **kwargs):
        return call(lambda: method(self, *args, **kwargs), self.url)

    wrapper.__name__ = wrapper.__qualname__ = name
    wrapper.__doc__ = method.__doc__
    return wrapper


# The private methods Optuna's cache (_CachedStorage, which wraps every study's RDBStorage) calls on its
# backend directly: new trials, parameters, every trial list. Left unwrapped, a restart that met one of them
# stopped the search with StorageInternalError instead of a wait.
CACHE_CALLS = ("_create_new_trial", "_set_trial_param", "_get_trials", "_get_best_trial_id", "_get_stale_trial_ids")

# Methods that do not reach the database (or manage it): called as they are.
NO_DATABASE = ("remove_session", "upgrade", "get_current_version", "get_head_version", "get_all_versions",
               "get_heartbeat_interval", "get_failed_trial_callback", "get_heartbeat_stale_trial_callback")

for _name in [n for n in dir(RDBStorage) if (not n.startswith("_") or n in CACHE_CALLS)
              and callable(getattr(RDBStorage, n)) and n not in NO_DATABASE]:
    setattr(PatientStorage, _name, _patient(_name))


def count_trials(study, states, attr: str | None = None) -> int:
    """How many of the study's trials are in `states` (and, with `attr`, carry that user attribute), counted by the
    database (one SQL count, patient on a database server): the trial loop counts before every batch, and listing
    the trials to count them read every trial of a long study each time (and, through Optuna's cache, kept them
    all in memory). A storage that is not a database (Optuna's in-memory one) lists them."""
    from sqlalchemy import func

    store = getattr(study._storage, "_backend", study._storage)  # under Optuna's cache: its database
    if not isinstance(store, RDBStorage):
        trials = study.get_trials(deepcopy=False, states=tuple(states))
        return len([t for t in trials if attr is None or attr in t.user_attrs])
    from optuna.storages._rdb.models import TrialModel, TrialUserAttributeModel

    def count() -> int:
        session = store.scoped_session()
        try:
            query = session.query(func.count(TrialModel.trial_id)).filter(
                TrialModel.study_id == study._study_id, TrialModel.state.in_(list(states)))
            if attr is not None:
                query = query.join(TrialUserAttributeModel, TrialUserAttributeModel.trial_id == TrialModel.trial_id
                                   ).filter(TrialUserAttributeModel.key == attr)
            return int(query.scalar())
        finally:
            session.rollback()  # read only; the connection goes back to the pool
            store.scoped_session.remove()

    return call(count, store.url)


def open_storage(url: str, **kwargs) -> RDBStorage:
    """A database server's storage, patient from its first connection (pool_pre_ping: a pooled connection
    the restart cut is replaced, not used)."""
    engine = {**kwargs.pop("engine_kwargs", {}), "pool_pre_ping": True}
    return call(lambda: PatientStorage(url, engine_kwargs=engine, **kwargs), url)


class _AdvisoryLock:
    """PostgreSQL's session-level advisory lock on one connection of this process. Re-entrant, as the
    file lock is: the server counts a session's acquisitions."""

    def __init__(self, url: str):
        self.url, self.key = url, int.from_bytes(hashlib.sha1(b"garage_exp study " + url.encode()).digest()[:8],
                                                 "big", signed=True)
        self.guard, self.connection = threading.RLock(), None

    def _execute(self, sql: str) -> None:
        from sqlalchemy import create_engine, text
        from sqlalchemy.pool import NullPool

        if self.connection is None:
            self.connection = create_engine(self.url, poolclass=NullPool).connect()
        try:
            self.connection.execute(text(sql), {"k": self.key})
            self.connection.commit()
        except Exception:
            self.connection = None  # a cut connection lost its locks with its session: start again
            raise

    def __enter__(self):
        self.guard.acquire()
        try:
            call(lambda: self._execute("SELECT pg_advisory_lock(:k)"), self.url)
        except BaseException:
            self.guard.release()
            raise
        return self

    def __exit__(self, *exc):
        try:
            with contextlib.suppress(Exception):  # a cut connection released the lock with its session
                if self.connection is not None:
                    self._execute("SELECT pg_advisory_unlock(:k)")
        finally:
            self.guard.release()


_locks: dict[str, _AdvisoryLock] = STATE.cache("search.storage.locks", "process")


def storage_lock(url: str):
    """The lock the workers of one study share (see the module's doc)."""
    from pathlib import Path
    from urllib.parse import urlparse

    if url.startswith("sqlite:///"):
        from filelock import FileLock

        return FileLock(str(Path(urlparse(url).path)) + ".lock")
    if url.startswith("postgresql"):
        return _locks.setdefault(url, _AdvisoryLock(url))
    return contextlib.nullcontext()

