"""The Optuna study of a search: its storage, name, directions and sampler.

The study lives in Optuna's RDB storage (sqlite under outputs/search/ unless `search.storage` names another, a
PostgreSQL URL on a cluster), so that it outlives the process: the same command (or `search.study=NAME`)
continues it, and several workers on one storage share it (Optuna's own pattern).
"""

from __future__ import annotations

import hashlib

import optuna

from garage_exp.core.errors import GarageError
from garage_exp.core.paths import OUTPUTS_DIR
from garage_exp.search import storage
from garage_exp.search.objectives import OBJECTIVES, shown

SAMPLERS = ("tpe", "cmaes", "gp", "random", "qmc", "nsga2", "saltelli", "grid", "archive")
MULTI_SAMPLERS = ("nsga2", "tpe", "random", "qmc")  # those that take several values (an objective's `multi`)
MODES = ("search", "suite")
# Trials a lost worker left RUNNING are failed once their heartbeat is this old (Optuna's heartbeat).
HEARTBEAT_S, GRACE_S = 30, 120


def quiet_optuna() -> None:
    """Ask/tell with Optuna's heartbeat is what its docs describe for `optimize`'s workers; its warnings about
    that (and the heartbeat, QMC and fail_stale_trials being experimental since 2.9-3.0) would print on every
    trial."""
    import warnings

    warnings.filterwarnings("ignore", message="Heartbeat of storage is supposed to be used", category=UserWarning)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)


def default_storage() -> str:
    return f"sqlite:///{OUTPUTS_DIR / 'search' / 'optuna.db'}"


def storage_lock(url: str):
    """Counting a study's trials then asking for one, or creating its tables, as one step for all workers
    (garage_exp.search.storage)."""
    return storage.storage_lock(url)


def storage_url(search) -> str:
    return str(search.storage) if search.storage else default_storage()


def study_name(search, fixed_and_space: list[str]) -> str:
    """`search.study`, else a name from the command (its overrides, sorted): the same command continues the
    same study, a different space starts another."""
    if search.study:
        return str(search.study)
    # what a worker or a resume may change without changing the study: its length, where it is logged
    ignored = ("search.trials=", "resume=", "tracking.", "hydra.", "search.storage=")
    text = " ".join(sorted(a for a in fixed_and_space if not a.startswith(ignored)))
    return "search-" + hashlib.sha1(text.encode()).hexdigest()[:10]


RUNS = ("per_trial", "per_search")  # search.runs: an MLflow run per trial, or one per search


def check_search(search) -> None:
    """The `search` node's own values (the space is checked by space.build)."""
    if search.mode not in MODES:
        raise GarageError(f"unknown mode {search.mode!r} ({' | '.join(MODES)})", "search.mode")
    if search.sampler not in SAMPLERS:
        raise GarageError(f"unknown sampler {search.sampler!r} ({' | '.join(SAMPLERS)})", "search.sampler")
    if search.objective not in OBJECTIVES:
        raise GarageError(f"unknown objective {search.objective!r} ({' | '.join(OBJECTIVES)})", "search.objective")
    goal = OBJECTIVES[search.objective]
    if goal.multi and search.sampler not in MULTI_SAMPLERS:
        raise GarageError(f"the {goal.name} objective needs a multi-objective sampler ({', '.join(MULTI_SAMPLERS)}), "
                          f"not {search.sampler}", "search.sampler")
    from garage_exp.search.prescreen import check_prescreen

    check_prescreen(search.prescreen)
    from garage_exp.search.require import check_require

    check_require(search.require)
    if goal.screen is None and search.prescreen.level != "none":
        screened = " or ".join(o.name for o in OBJECTIVES.values() if o.screen is not None)
        raise GarageError(f"the pre-screen serves one objective ({screened}), not {search.objective}",
                          "search.prescreen.level")
    if int(search.grid_levels) < 2:
        raise GarageError(f"{search.grid_levels} levels: a grid needs at least 2 (its ends)", "search.grid_levels")
    if int(search.startup) < 0:
        raise GarageError(f"{search.startup} startup trials: at least 0", "search.startup")
    if int(search.get("batch", 1)) < 1:
        raise GarageError(f"a batch of {search.batch} trials: at least 1", "search.batch")
    from garage_exp.search.cpus import parse

    parse(search.get("cpus"))
    if search.get("runs", "per_trial") not in RUNS:
        raise GarageError(f"unknown runs {search.runs!r} ({' | '.join(RUNS)})", "search.runs")
    if int(search.trials) < 1:
        raise GarageError(f"{search.trials} trials: at least 1", "search.trials")
    if int(search.get("frames") or 0) < 0:
        raise GarageError(f"a budget of {search.frames} frames: at least 0 (0: none)", "search.frames")
    if not 0.0 <= float(search.min_visible) <= 1.0:
        raise GarageError(f"{search.min_visible} is outside 0-1", "search.min_visible")
    if not 0.0 <= float(search.max_truncation) <= 1.0:
        raise GarageError(f"{search.max_truncation} is outside 0-1", "search.max_truncation")
    if int(search.min_box) < 0:
        raise GarageError(f"{search.min_box} is negative", "search.min_box")
    _check_archive(search, goal)
    levels = int(search.suite.get("levels") or 0)
    if levels and search.suite.bands:
        raise GarageError("a suite has either bands or levels, not both", "search.suite.levels")
    if levels:  # 0: the bands; else at least 2
        from garage_exp.search.suite import level_bands

        level_bands(levels)
    for band, edges in search.suite.bands.items():
        if len(edges) != 2 or not float(edges[0]) < float(edges[1]):
            raise GarageError(f"a band is [low, high) with low < high, not {list(edges)}", f"search.suite.bands.{band}")


def _check_archive(search, goal) -> None:
    """The descriptors (garage_exp/search/archive.py) and the archive sampler's settings."""
    from garage_exp.search.archive import EMITTERS, PARENTS, check_descriptors

    check_descriptors(search.descriptors)
    if search.sampler == "archive":
        if not goal.confidence or goal.multi:
            raise GarageError(f"the archive's cells keep the hardest trial by difficulty: search.objective=difficulty,"
                              f" not {goal.name}", "search.sampler")
        if not search.descriptors:
            raise GarageError("the archive needs at least one descriptor", "search.descriptors")
    if search.archive.emitter not in EMITTERS:
        raise GarageError(f"unknown emitter {search.archive.emitter!r} ({' | '.join(EMITTERS)})",
                          "search.archive.emitter")
    parents = str(search.archive.get("parents", "uniform"))
    if parents not in PARENTS:
        raise GarageError(f"unknown choice of parents {parents!r} ({' | '.join(PARENTS)})", "search.archive.parents")
    if not float(search.archive.sigma) > 0:
        raise GarageError(f"{search.archive.sigma}: the mutation's spread must be positive", "search.archive.sigma")
    if not 0.0 <= float(search.archive.failure) <= 1.0:
        raise GarageError(f"{search.archive.failure} is outside 0-1", "search.archive.failure")


def grid(params: dict, levels: int) -> dict[str, list]:
    """The grid a person would write over the same space: each interval at `levels` evenly spaced values
    (ends included), each choice at all its values."""
    import numpy as np

    out = {}
    for name, dist in params.items():
        if isinstance(dist, optuna.distributions.CategoricalDistribution):
            out[name] = list(dist.choices)
        elif isinstance(dist, optuna.distributions.IntDistribution):
            out[name] = sorted({int(round(v)) for v in np.linspace(dist.low, dist.high, levels)})
        else:
            out[name] = [round(float(v), 6) for v in np.linspace(dist.low, dist.high, levels)]
    return out


def grid_size(params: dict, levels: int) -> int:
    import math

    return math.prod(len(v) for v in grid(params, levels).values())


class _Grid(optuna.samplers.GridSampler):
    """Optuna's grid sampler stops `optimize` when the grid is done (Study.stop, refused outside optimize);
    the search's loop stops at the grid's size itself."""

    def after_trial(self, study, trial, state, values) -> None:
        pass


def trial_seed(seed: int, number: int) -> int:
    """The random state of trial `number` of a study seeded `seed` (as search/archive.py seeds its emitters: by the
    study's seed and the trial's number)."""
    import numpy as np

    return int(np.random.SeedSequence([int(seed), int(number)]).generate_state(1)[0])


class NumberedRandom(optuna.samplers.RandomSampler):
    """Optuna's random sampler with each trial's draws a function of the seed and the trial's number.

    Optuna's own keeps one stream per process from its seed, so every process that opens a seeded study starts it
    again: a second worker on the same storage drew the first worker's scenarios, and a resumed search drew its
    first trials again. Seeded by the trial's number, workers and resumes draw what one uninterrupted search draws.
    """

    def __init__(self, seed: int | None = None) -> None:
        super().__init__(seed=seed)
        self._seed = seed

    def before_trial(self, study, trial) -> None:
        if self._seed is not None:  # unseeded: Optuna's fresh stream, as before
            self._rng.rng.seed(trial_seed(self._seed, trial.number))


class NumberedTPE(optuna.samplers.TPESampler):
    """TPE whose random state is set from the seed and the trial's number before each trial (see NumberedRandom):
    its first `n_startup_trials` are NumberedRandom's, and two workers that see the same history still draw
    different candidates."""

    def __init__(self, seed: int | None = None, **kwargs) -> None:
        super().__init__(seed=seed, **kwargs)
        self._seed = seed
        self._random_sampler = NumberedRandom(seed)  # the startup trials' sampler (Optuna's attribute)

    def before_trial(self, study, trial) -> None:
        if self._seed is not None:
            self._rng.rng.seed(trial_seed(self._seed, trial.number) ^ 0x5A5A5A5A)  # not the startup's stream
        super().before_trial(study, trial)


def sampler(search, seed: int, params: dict | None = None) -> optuna.samplers.BaseSampler:
    name = search.sampler
    if name == "grid":
        return _Grid(grid(params or {}, int(search.grid_levels)), seed=seed)
    if name == "tpe":
        # multivariate: factors of a scenario interact (a dark garage and a far target), as TPE's docs advise
        # constant_liar: trials asked before the running ones are told (search.batch > 1, or several workers)
        # are kept away from those, as Optuna advises for batch and distributed optimisation
        return NumberedTPE(seed=seed, multivariate=True, n_startup_trials=int(search.startup),
                           constant_liar=int(search.get("batch", 1)) > 1)
    if name == "cmaes":
        # CMA-ES samples the continuous factors; categorical ones fall back to TPE (warn_independent off: said here)
        return optuna.samplers.CmaEsSampler(seed=seed, warn_independent_sampling=False,
                                            n_startup_trials=int(search.startup),
                                            independent_sampler=optuna.samplers.TPESampler(seed=seed))
    if name == "gp":  # Optuna's Gaussian-process Bayesian optimisation (torch on the CPU)
        return optuna.samplers.GPSampler(seed=seed, n_startup_trials=int(search.startup),
                                         independent_sampler=NumberedRandom(seed=seed))
    if name == "nsga2":
        return optuna.samplers.NSGAIISampler(seed=seed)
    if name == "archive":  # quality diversity: ribs' MAP-Elites over the descriptors' cells (search/archive.py)
        from garage_exp.search.archive import ArchiveSampler

        return ArchiveSampler(params or {}, search.descriptors, seed, int(search.startup),
                              str(search.archive.emitter), float(search.archive.sigma),
                              str(search.archive.get("parents", "uniform")), float(search.archive.failure))
    if name == "qmc":
        return optuna.samplers.QMCSampler(qmc_type="sobol", scramble=True, seed=seed, warn_independent_sampling=False)
    return NumberedRandom(seed=seed)  # random; saltelli enqueues its design, random fills the rest


def _write_ahead(storage) -> None:
    """sqlite in write-ahead-log mode with NORMAL sync: a trial makes a dozen commits (ask, its attributes, tell),
    and a bare commit measured 2 ms with sqlite's default journal against 0.02 ms so; readers (optuna-dashboard,
    another worker) do not block the writer.
    A commit survives a crash of the process; only a power cut may lose the last ones."""
    from sqlalchemy import event

    def pragmas(connection, _record):
        cursor = connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=NORMAL")
        cursor.close()

    event.listen(storage.engine, "connect", pragmas)
    storage.engine.dispose()  # connections opened before the listener get the pragmas too


def lean(study: optuna.Study, search) -> optuna.Study:
    """The study as a trial loop should hold it. Optuna's cache (which it puts over every database storage) keeps
    every trial in the process, ~5 kB each, for samplers that read the history; the random sampler reads none and
    the loop counts in the database (storage.count_trials), so its loop gets a twin of the study that talks to the
    database directly, and a search of 10,000 trials keeps none of them in memory (benchmarks/studies/soak.py).
    The study itself keeps its cache: the analysis after the loop reads every trial several times."""
    import copy

    if search.sampler != "random" or search.mode != "search":
        return study
    twin = copy.copy(study)
    twin._storage = getattr(study._storage, "_backend", study._storage)
    return twin


def open_study(search, name: str, seed: int, params: dict | None = None) -> optuna.Study:
    """Create the study, or load it when it exists (resume, a second worker). A study made with other
    directions (another objective under the same name) is refused."""
    from pathlib import Path
    from urllib.parse import urlparse

    quiet_optuna()
    url = storage_url(search)
    if url.startswith("sqlite:///"):
        Path(urlparse(url).path).parent.mkdir(parents=True, exist_ok=True)
    goal = OBJECTIVES[search.objective]
    directions = list(goal.directions)
    with storage_lock(url):
        if url.startswith("sqlite"):
            store = optuna.storages.RDBStorage(url, heartbeat_interval=HEARTBEAT_S, grace_period=GRACE_S,
                                               engine_kwargs={"connect_args": {"timeout": 60}})
            _write_ahead(store)
        else:  # a database server: patient while it restarts
            store = storage.open_storage(url, heartbeat_interval=HEARTBEAT_S, grace_period=GRACE_S)
        try:
            study = optuna.create_study(storage=store, study_name=name, directions=directions,
                                        sampler=sampler(search, seed, params), load_if_exists=True)
        except ValueError as exc:
            raise GarageError(f"study {name!r} in {url}: {exc}", "search.study") from None
    held = study.user_attrs.get("direction_names")  # what its values are: another objective's must not mix in
    if [d.name.lower() for d in study.directions] != directions or (held and list(held) != list(goal.metrics)):
        made = f"{', '.join(held)}" if held else f"{len(study.directions)} values"
        raise GarageError(f"study {name!r} was made for another objective ({made}, not {', '.join(goal.metrics)}); "
                          "give another search.study", "search.objective")
    study.set_user_attr("direction_names", list(goal.metrics))  # the analysis names its columns from these
    study.set_user_attr("untestable", goal.untestable)  # and says why a pruned trial was infeasible
    study.set_user_attr("attr_headings", shown())  # and which trial attributes it shows, headed how
    study.set_metric_names(list(goal.metrics))  # optuna-dashboard's axis labels
    return study
