"""A trial's parameters, and its attributes, written to the study's database in one transaction.

Optuna's ask writes each parameter as it is drawn: one transaction apiece, each looking its trial up again. The
wide space draws 33 parameters a trial, and a search of its one-shot scenarios asks about 3.5 draws for each one
it renders (the rest rejected by the space's requirements, or infeasible), so its asks took ~22 ms each, about
a tenth of a rendered scenario's time. `params_at_once` holds the parameters of the trials asked inside it and
writes them when it ends, as Optuna's own `create_new_trial(template_trial=...)` writes an enqueued trial's: the
trial looked up and checked once, every row added in one session. Nothing reads them from the database before
then: a trial's own draw reads its cached frozen trial, and another worker reads finished trials only. What is
written, and each check Optuna makes on a parameter (a distribution that contradicts the study's), is the same.
`attrs_at_once` does the same for user attributes set together (a draw's overrides and worker; a finished
trial's outcome, a dozen, before it is told). `told_from_its_copy` spares a tell its read of the trial, and
`asked_without_reading` an ask its read of the trial it has just made.
"""

from __future__ import annotations

import contextlib
import copy
import json
import sqlite3

from optuna.storages import RDBStorage

from garage_exp.core.state import STATE


def backend(study):
    """The study's database storage under Optuna's cache, or None when it is not a database."""
    store = getattr(study._storage, "_backend", study._storage)
    return store if isinstance(store, RDBStorage) else None


@contextlib.contextmanager
def params_at_once(study):
    """Inside: the study's new trials' parameters are held; on leaving, written in one transaction per trial (on a
    database that goes away, patiently: search/storage.call). An exception inside writes nothing: the trials
    it leaves half-asked are failed by their heartbeats, as a worker's that died mid-ask."""
    with _held(study, "_set_trial_param", lambda held: lambda trial_id, *rest: held.setdefault(
            trial_id, []).append(rest)) as (store, held):
        yield
    for trial_id, rows in held.items():
        write(store, trial_id, rows)


@contextlib.contextmanager
def attrs_at_once(study):
    """Inside: user attributes set on the study's trials are held (each trial's cached copy has them at once); on
    leaving, written in one transaction per trial, the last value of a key as the last write would leave it."""
    with _held(study, "set_trial_user_attr", lambda held: lambda trial_id, key, value: held.setdefault(
            trial_id, {}).__setitem__(key, value)) as (store, held):
        yield
    for trial_id, attrs in held.items():
        write_attrs(store, trial_id, attrs)


@contextlib.contextmanager
def told_from_its_copy(study, trial):
    """Inside: Optuna's tell of `trial` takes the trial from its own copy (the one the trial keeps of what it
    drew and set) instead of reading it back from the database. Optuna's tell reads the running trial first, all
    its parameters and attributes (~10 ms on the wide space, a tell a draw), only to check that it runs and hand it
    to the sampler. Only a study that talks to its database directly (`study.lean`: the random sampler, which
    reads neither the trial's system attributes nor its history) is so told: a sampler that sets system
    attributes through the storage leaves the trial's copy without them. What the tell writes is the same; a
    trial another worker failed meanwhile is still refused, by the database's check on the write."""
    store = study._storage
    if not isinstance(store, RDBStorage):  # Optuna's cache over it: a sampler that reads the history
        yield
        return

    def get_trial(trial_id: int):
        if trial_id == trial._trial_id:
            return copy.deepcopy(trial._cached_frozen_trial)
        return type(store).get_trial(store, trial_id)

    with _held(study, "get_trial", lambda held: get_trial):
        yield


@contextlib.contextmanager
def asked_without_reading(study):
    """Inside: a trial the study makes is not read back from the database. Optuna's ask creates the trial's row,
    which hands back the trial as written (RDBStorage._create_new_trial), then reads the same trial again to give
    it its cached copy (Trial.__init__: get_trial, ~1 ms with its parameter, attribute and value queries; about
    3.5 asks a rendered one-shot scenario). Here the copy is the one the write handed back. Only a study that talks
    to its database directly (`study.lean`) is so asked: Optuna's cache over a database already keeps what it
    created. A trial made from a template (an enqueued one) is read back as ever."""
    store = study._storage
    if not isinstance(store, RDBStorage) or "create_new_trial" in vars(store) or "get_trial" in vars(store):
        yield
        return
    made: dict = {}

    def create_new_trial(study_id: int, template_trial=None) -> int:
        if template_trial is not None:
            return type(store).create_new_trial(store, study_id, template_trial)
        frozen = store._create_new_trial(study_id)
        made[frozen._trial_id] = frozen
        return frozen._trial_id

    def get_trial(trial_id: int):
        frozen = made.pop(trial_id, None)
        return type(store).get_trial(store, trial_id) if frozen is None else frozen

    store.create_new_trial, store.get_trial = create_new_trial, get_trial
    try:
        yield
    finally:
        del store.create_new_trial, store.get_trial  # the class's own again


@contextlib.contextmanager
def _held(study, method: str, holder):
    """The study's database storage with `method` replaced by `holder(held)` on this instance while inside, and
    `held`; a storage that is no database, or a method held already (re-entered), is left as it is (and nothing
    is held)."""
    store, held = backend(study), {}
    if store is None or method in vars(store):
        yield store, held
        return
    setattr(store, method, holder(held))
    try:
        yield store, held
    except BaseException:
        held.clear()  # written nothing
        raise
    finally:
        delattr(store, method)  # the class's own again


def write(store: RDBStorage, trial_id: int, rows: list[tuple]) -> None:
    """One trial's parameters (name, internal value, distribution, the study's distribution or None), as Optuna's
    `_set_trial_param` writes each, in one session."""
    from optuna.storages._rdb import models
    from optuna.storages._rdb.storage import _create_scoped_session
    from optuna import distributions
    from sqlalchemy import insert

    from garage_exp.search.storage import call

    def commit() -> None:
        with _create_scoped_session(store.scoped_session, True) as session:
            trial = models.TrialModel.find_or_raise_by_id(trial_id, session)
            store.check_trial_is_updatable(trial_id, trial.state)
            # The study's distribution of each parameter, which Optuna looks up (a query a parameter) when its cache
            # does not give it: read once per study and kept on the storage, as its cache keeps it.
            known = vars(store).setdefault("_garage_distributions", {}).setdefault(trial.study_id, {})
            for name, value, distribution, previous in rows:
                previous = previous or known.get(name)
                if previous is None:  # the first of this parameter this process writes: as Optuna checks it
                    record = (session.query(models.TrialParamModel).join(models.TrialModel)
                              .filter(models.TrialModel.study_id == trial.study_id)
                              .filter(models.TrialParamModel.param_name == name).first())
                    previous = None if record is None else distributions.json_to_distribution(
                        record.distribution_json)
                known.setdefault(name, previous or distribution)
                if previous is not None:
                    distributions.check_distribution_compatibility(previous, distribution)
            # One bulk INSERT of plain rows: the ORM's flush of 33 new objects took more than the rows' writing.
            session.execute(insert(models.TrialParamModel), [
                {"trial_id": trial_id, "param_name": name, "param_value": value,
                 "distribution_json": distributions.distribution_to_json(distribution)}
                for name, value, distribution, _ in rows])

    call(commit, store.url)


def write_attrs(store: RDBStorage, trial_id: int, attrs: dict) -> None:
    """One trial's user attributes, as Optuna's `set_trial_user_attr` writes each (an upsert), in one session: the
    trial looked up and checked once, and the rows upserted by one statement run for all of them. Optuna's own
    write looked the trial up again and built its statement anew for every key (about 1.5 ms a key in Python;
    a one-shot draw of the wide space sets about a dozen). A database with no upsert statement of ours (neither
    SQLite, PostgreSQL nor MySQL) gets Optuna's writes, key by key."""
    from optuna.storages._rdb import models
    from optuna.storages._rdb.storage import _create_scoped_session

    from garage_exp.search.storage import call

    upsert = _attr_upsert(store.engine.name)

    def commit() -> None:
        with _create_scoped_session(store.scoped_session, True) as session:
            if upsert is None:
                for key, value in attrs.items():
                    store._set_trial_attr_without_commit(session, models.TrialUserAttributeModel, trial_id, key,
                                                         value)
                return
            trial = models.TrialModel.find_or_raise_by_id(trial_id, session)
            store.check_trial_is_updatable(trial_id, trial.state)
            session.execute(upsert, [{"trial_id": trial_id, "key": key, "value_json": json.dumps(value)}
                                     for key, value in attrs.items()])

    if attrs:
        call(commit, store.url)


@STATE.memo("process", maxsize=8)  # one a dialect
def _attr_upsert(dialect: str):
    """The statement that inserts a user attribute or replaces its value (Optuna's, per dialect), made once so
    that SQLAlchemy compiles it once; None for a database Optuna writes otherwise."""
    from optuna.storages._rdb import models

    table = models.TrialUserAttributeModel
    if dialect == "mysql":
        from sqlalchemy.dialects.mysql import insert

        stmt = insert(table)
        return stmt.on_duplicate_key_update(value_json=stmt.inserted.value_json)
    if dialect == "sqlite" and sqlite3.sqlite_version_info >= (3, 24, 0) or dialect == "postgresql":
        from sqlalchemy.dialects import postgresql, sqlite

        stmt = (sqlite if dialect == "sqlite" else postgresql).insert(table)
        return stmt.on_conflict_do_update(index_elements=[table.trial_id, table.key],
                                          set_={"value_json": stmt.excluded.value_json})
    return None
