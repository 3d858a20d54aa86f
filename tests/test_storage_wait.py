"""The study's storage waits for a database server that restarts (garage_exp.search.storage), without a server:
the errors are the ones psycopg and SQLAlchemy raise (text measured against a stopped PostgreSQL 15)."""

import pytest
from sqlalchemy.exc import OperationalError

from garage_exp.core.exits import SweepStopped
from garage_exp.search import storage

REFUSED = 'connection failed: connection to server at "127.0.0.1", port 5432 failed: Connection refused'


def down(text=REFUSED):
    """What optuna raises: its StorageInternalError, caused by SQLAlchemy's OperationalError."""
    from optuna.exceptions import StorageInternalError

    try:
        raise OperationalError("SELECT 1", {}, Exception(text))
    except OperationalError as cause:
        try:
            raise StorageInternalError("An exception is raised during the commit.") from cause
        except StorageInternalError as exc:
            return exc


@pytest.mark.parametrize("text", [REFUSED, "server closed the connection unexpectedly",
                                  "FATAL: terminating connection due to administrator command",
                                  "FATAL: the database system is starting up"])
def test_a_database_away_is_recognised_along_the_causes(text):
    assert storage.is_down(down(text))


@pytest.mark.parametrize("exc", [ValueError("no study named x"), KeyError("trial"),
                                 OperationalError("SELECT", {}, Exception('relation "trials" does not exist'))])
def test_a_bad_query_is_not_waited_for(exc):
    assert not storage.is_down(exc)


def test_the_wait_is_one_line_each_way_and_the_call_goes_through(monkeypatch, capsys):
    monkeypatch.setattr(storage.time, "sleep", lambda s: None)
    calls = []

    def fn():
        calls.append(1)
        if len(calls) < 4:
            raise down()
        return "ok"

    assert storage.call(fn, "postgresql://user:secret@db:5432/optuna") == "ok"
    err = capsys.readouterr().err.splitlines()
    assert len(calls) == 4 and len(err) == 2, err
    assert err[0].startswith("garage_exp: optuna storage postgresql://user:***@db:5432/optuna not answering")
    assert "secret" not in "".join(err) and err[1].startswith("garage_exp: optuna storage") and "answers again" in err[1]


def test_a_wait_that_ended_in_another_error_does_not_shorten_the_next(monkeypatch, capsys):
    """Found on the cluster: a first outage ended by a bad query left its start behind, and the next outage,
    minutes later, stopped the sweep at once as "did not answer for 120 s"."""
    monkeypatch.setattr(storage.time, "sleep", lambda s: None)
    clock = iter([0.0, 500.0, 501.0, 502.0])
    monkeypatch.setattr(storage.time, "monotonic", lambda: next(clock))
    errors = iter([down(), ValueError("bad query")])

    def first():
        raise next(errors)

    with pytest.raises(ValueError):
        storage.call(first, "postgresql://db/optuna")
    later = iter([down(), "ok"])

    def second():
        value = next(later)
        if isinstance(value, Exception):
            raise value
        return value

    assert storage.call(second, "postgresql://db/optuna") == "ok"  # waited from its own start, 500 s later


def test_a_database_that_stays_away_stops_the_sweep(monkeypatch, capsys):
    monkeypatch.setenv("GARAGE_EXP_STORAGE_WAIT", "0")

    def fn():
        raise down()

    with pytest.raises(SweepStopped, match="did not answer"):
        storage.call(fn, "postgresql://db/optuna")
    with pytest.raises(ValueError):  # its own error is not waited for
        storage.call(lambda: (_ for _ in ()).throw(ValueError("bad")), "postgresql://db/optuna")


def test_each_storage_method_is_patient():
    from optuna.storages import RDBStorage

    for name in ("create_new_trial", "set_trial_state_values", "get_all_trials", "record_heartbeat",
                 "get_n_trials", "create_new_study"):
        assert getattr(storage.PatientStorage, name) is not getattr(RDBStorage, name), name


def test_what_optunas_cache_calls_on_its_backend_is_patient():
    """Optuna's _CachedStorage calls some private methods of the RDBStorage directly; each must wait too (a
    restart met in `_get_trials` stopped a search on two Ray nodes)."""
    import inspect
    import re

    from optuna.storages import RDBStorage, _cached_storage

    called = set(re.findall(r"self\._backend\.(\w+)\(", inspect.getsource(_cached_storage)))
    assert {"_create_new_trial", "_get_trials"} <= called
    for name in called - set(storage.NO_DATABASE):
        assert getattr(storage.PatientStorage, name) is not getattr(RDBStorage, name), name


def test_the_lock_fits_the_store(tmp_path):
    from filelock import FileLock

    assert isinstance(storage.storage_lock(f"sqlite:///{tmp_path}/o.db"), FileLock)
    lock = storage.storage_lock("postgresql://db/optuna")
    assert lock is storage.storage_lock("postgresql://db/optuna")  # one per URL and process: re-entrant
