"""The MLflow client of a store, and waiting out a store or tracking server that does not answer.

One MLflow idiom: every call goes through an `MlflowClient` made for an explicit URI (`client(uri)`), never
through MLflow's fluent API (active runs, `mlflow.set_tracking_uri`); a job's run is logged by run id
(jobrun.JobRun). The URI is exported to the environment as $MLFLOW_TRACKING_URI (what the fluent API's
set_tracking_uri did here before): child processes (the sweep's workers) inherit the store this process writes
to, and `tracking_uri(None)` and the outage messages name it from then on.
"""

from __future__ import annotations

import contextlib
import os
import random
import sys
import time

from garage_exp.core.environment import prepare_environment
from garage_exp.core.paths import OUTPUTS_DIR
from garage_exp.core.state import STATE

# sqlite answers "database is locked" (or "database table is locked") when another process holds the write
# lock longer than its busy timeout; the write did not happen and is safe to repeat.
TRANSIENT = ("database is locked", "database table is locked")

# Two workers of one search that write the same key of one run at once (the search's parent run: its tags, at
# each worker's end): MLflow's store looks the row up, then inserts it, and the later insert fails on the key.
# The other worker's row is there then: the write, repeated, finds it and updates it. Repeated a few times only:
# a key that stays taken is a real conflict.
RACED = ("unique constraint failed", "duplicate key value violates unique constraint")
RACED_ATTEMPTS = 3

# A tracking server that does not answer: refused or reset connections, timeouts, a proxy's 502-504; or a
# server whose PostgreSQL store restarts (it answers 503, or 500 with the driver's text, until the database is
# back).
UNREACHABLE = ("max retries exceeded", "connection refused", "connection aborted", "connection reset",
               "read timed out", "connecttimeout", "remotedisconnected", "failed to establish a new connection",
               "error code 429", "error code 502", "error code 503", "error code 504",
               "server closed the connection unexpectedly", "terminating connection due to administrator command",
               "the database system is shutting down", "the database system is starting up",
               "the database system is in recovery mode", "could not connect to server", "connection to server at")


def tracking_uri(uri: str | None = None) -> str:
    """Config override, then $MLFLOW_TRACKING_URI, then the project's sqlite store (absolute, cwd-proof)."""
    if uri:
        return uri
    if os.environ.get("MLFLOW_TRACKING_URI"):
        return os.environ["MLFLOW_TRACKING_URI"]
    OUTPUTS_DIR.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{OUTPUTS_DIR / 'mlflow.db'}"


# One client per store for the command: making one costs ~60 ms (MLflow resolves its store and registry), which
# a search paid on every trial.
_CLIENTS: dict[str, object] = STATE.cache("tracking.clients", "command")


def client(uri: str | None = None):
    """An MlflowClient of the store `uri` names (see tracking_uri), the store created on first use; the same
    client for the rest of the command."""
    uri = tracking_uri(uri)
    prepare_environment(uri)  # $MLFLOW_TRACKING_URI for child processes and the outage messages (the module's doc)
    if uri not in _CLIENTS:
        import mlflow  # imported lazily: it costs ~1 s and plan-only commands do not need it

        from garage_exp.tracking.store import open_store

        # The client opens (and may create) the store: a write, made once under the store's lock.
        _CLIENTS[uri] = open_store(uri, lambda: retry(lambda: mlflow.MlflowClient(uri)))
    return _CLIENTS[uri]


def existing_client(uri: str | None = None):
    """client() of a store that must hold runs already (a report, the UI's links): a sqlite store that does not
    exist is bad input (GarageError naming it), not created empty."""
    from garage_exp.core.errors import GarageError
    from garage_exp.tracking.store import sqlite_path

    path = sqlite_path(tracking_uri(uri))
    if path is not None and not path.is_file():
        raise GarageError("no MLflow store here (a run or a sweep makes one)", str(path))
    return client(uri)


class TrackingAway(Exception):
    """The tracking server stayed away longer than the wait allowed (or a signal came while it was away)."""


def tracking_wait() -> float:
    """How long a call waits for a tracking server that went away ($GARAGE_EXP_TRACKING_WAIT, seconds)."""
    from garage_exp.core.exits import wait_seconds

    return wait_seconds("GARAGE_EXP_TRACKING_WAIT")


def _unreachable(exc: BaseException) -> bool:
    text = f"{type(exc).__name__}: {exc}".lower()
    return any(t in text for t in UNREACHABLE)


def retry(fn, attempts: int = 10, base_delay: float = 0.1, max_delay: float = 5.0):
    """Call fn(), retrying on sqlite's 'database is locked' (several workers share one sqlite store) with
    jittered exponential back-off (~30 s in all before the error is raised), a few times on a key another worker
    wrote at the same moment (RACED), and on a tracking server that does not answer for up to tracking_wait()
    seconds (one line when the wait starts, one when the server is back), then TrackingAway. After Ctrl-C or
    SIGTERM nothing waits: one attempt, and none at all when the server was already away."""
    from garage_exp.core.exits import signals_held, stopping

    k = 0
    while True:
        if STATE.tracking_given_up or (stopping() and STATE.tracking_down_since is not None):
            raise TrackingAway(f"tracking server {_uri()} away")
        try:
            # A database's session holds a signal until it ends; a server's request may be cut (nothing is left
            # locked here).
            with signals_held() if _database(_uri()) else contextlib.nullcontext():
                result = fn()
        except Exception as exc:  # MlflowException wraps sqlalchemy's OperationalError and requests' errors
            if _unreachable(exc):
                now = time.monotonic()
                if STATE.tracking_down_since is None:
                    STATE.tracking_down_since = now
                    if not stopping():
                        print(f"garage_exp: tracking server {_uri()} not answering; retrying for up to "
                              f"{tracking_wait():.0f} s (GARAGE_EXP_TRACKING_WAIT)", file=sys.stderr, flush=True)
                waited = now - STATE.tracking_down_since
                if stopping() or waited >= tracking_wait():
                    STATE.tracking_given_up = not stopping()
                    raise TrackingAway(f"tracking server {_uri()} away for {waited:.0f} s") from None
                time.sleep(min(30.0, 2.0 ** min(k, 5), tracking_wait() - waited + 0.01))
                k += 1
                continue
            text = str(exc).lower()
            raced = any(t in text for t in RACED)
            if not (raced or any(t in text for t in TRANSIENT)) or k >= (RACED_ATTEMPTS if raced else attempts) - 1:
                raise
            time.sleep(min(max_delay, base_delay * (2**k)) * (0.5 + random.random()))
            k += 1
            continue
        if STATE.tracking_down_since is not None:
            print(f"garage_exp: tracking server {_uri()} answers again after {time.monotonic() - STATE.tracking_down_since:.0f} s",
                  file=sys.stderr, flush=True)
            STATE.tracking_down_since = None
        return result


def _database(uri: str) -> bool:
    """The store is a database this process opens itself (sqlite, PostgreSQL, MySQL, ...), not a tracking server
    or a folder."""
    from mlflow.store.db.db_types import DATABASE_ENGINES  # MLflow's own list: sqlite, postgresql, mysql, mssql

    return uri.split(":", 1)[0].split("+")[0].lower() in DATABASE_ENGINES


def _uri() -> str:
    """The store the last client() was made for, as its outage messages name it."""
    return tracking_uri()
