"""A search from start to end: check the space, open the study, run the trials, analyse, write the suite.

The Hydra sweeper (hydra_plugins/garage_search) is a thin shell around `run`; the sweep callback calls
`check` before it opens the parent run, so that a bad space costs nothing and writes nothing.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE
from garage_exp.search import space as space_mod
from garage_exp.search import study as study_mod
from garage_exp.search.compose import Compositions
from garage_exp.search.objectives import objective

log = logging.getLogger("garage_exp")
SWEEPER = "hydra_plugins.garage_search.sweeper.SearchSweeper"
_CHECKED: dict[tuple[str, ...], space_mod.Space] = STATE.cache("search.sweep.checked", "command")


def is_search(config: DictConfig) -> bool:
    return OmegaConf.select(config, "hydra.sweeper._target_") == SWEEPER


def arguments_of(config: DictConfig) -> list[str]:
    """The search's overrides: its space's (`space=NAME`) first, then the command's (which win for a key)."""
    return space_mod.expand(config, list(config.hydra.overrides.task))


def group_levels(loader) -> dict[str, list[str]]:
    """Each config group's levels as the loader sees them (the package's conf/ and a user's --config-dir).
    Asked of the loader's repository itself: the loader's `get_group_options` answers the same (no config and no
    overrides: no hydra.searchpath to add) from a deep copy of it, every schema in the ConfigStore included, made
    anew for each group (about a third of a bad search space's refusal)."""
    from hydra.core.object_type import ObjectType

    repo = loader.repository
    groups = {}
    for group in repo.get_group_options("", ObjectType.GROUP):
        if group == "hydra":
            continue
        groups[group] = [name for name in repo.get_group_options(group, ObjectType.CONFIG)
                         if not name.endswith("_schema")]
    return groups


def keep_on_cpus(config: DictConfig) -> None:
    """This worker kept on `search.cpus` (search/cpus.py), before its checks load the detector's process and its
    renderer makes its threads: they start on those CPUs, and so do the thread pools that read the process's CPUs
    once when they start (pinned afterwards, the detector's own thread and one of the renderer's moved back to
    both cores, measured). A setting that names no CPU here stops the command before anything is written."""
    from garage_exp.search import cpus

    value = OmegaConf.select(config, "search.cpus")
    if cpus.pin(cpus.parse(value)):
        print(f"garage_exp: this worker kept on CPU {value}")


def check(config: DictConfig, loader) -> space_mod.Space:
    """The search's settings and space, each value (an interval's ends and middle, each choice) and the space's
    middle composed and checked as a job would check it (no rendering): GarageError (one line naming the override) on the first problem. A point whose values put two
    actors in one another (core.errors.Infeasible) is no error of any one value: the search prunes such trials.
    The space is refused for it only when no probed point is feasible, naming the overrides that place those
    actors."""
    from garage_exp.core.errors import Infeasible
    from garage_exp.run.preflight import load_models, preflight

    arguments = tuple(arguments_of(config))
    space_mod.settle(config, list(arguments))  # a shipped space's requirements and cells, unless the command's
    if arguments in _CHECKED:
        return _CHECKED[arguments]
    study_mod.check_search(config.search)
    # resume continues the study (not a trial's job); a suite's dataset comes from its scenarios' reruns
    kept = [a for a in arguments if not a.startswith("resume=")
            and not (config.search.mode == "suite" and a.startswith("dataset="))]
    try:
        space = space_mod.build(kept, config, group_levels(loader))
    except GarageError as exc:  # an entry of the space's file: named by its file and index
        raise space_mod.in_space_file(exc, config) from None
    base = space_mod.default_point(space)
    infeasible: list[Infeasible] = []
    prepared = []  # (where, checked job) of each feasible point: their models are loaded last
    try:  # the fixed part first: a case the plan cannot hold is the command's problem, not a searched value's
        fixed = loader.load_sweep_config(config, space.fixed)
        prepared.append(("search", preflight(fixed, check_space=False, load=False)))
    except Infeasible as exc:  # at the searched keys' own defaults: the searched values may move them apart
        infeasible.append(exc)
    except GarageError as exc:
        raise GarageError(str(exc), "search") from None
    _check_objective(config.search, fixed)
    feasible = 0
    probes = [(name, {**base, name: value}) for name, value in space_mod.probe_points(space)]
    # every probe composed as the search's launcher composes a trial: once per combination of group levels
    compositions = Compositions(loader, config, group_levels(loader))
    for name, values in [*probes, (None, space_mod.middle_point(space))]:  # the first probe is `base` itself
        where = (f"search space {name}={space_mod.format_value(values[name])}" if name
                 else f"search space {' '.join(space.written.values())}")
        try:
            prepared.append((where, _probe(compositions, space.overrides(values), where)))
            feasible += 1
        except Infeasible as exc:
            infeasible.append(exc)
    if not feasible:
        exc = infeasible[-1]
        searched = list(space.written.values())
        blamed = space_mod.at_fault(searched, exc.actors) or space_mod.at_fault(space.fixed, exc.actors)
        raise GarageError(f"no probed point of the space is feasible ({len(probes) + 1} probed), e.g. {exc}",
                          f"search space {' '.join(blamed or searched)}")
    # Last, the one check that needs the models (seconds; a detector is loaded once per process, however many
    # points share it): a refusal above costs no model loading.
    for where, job in prepared:
        if where == "search":
            try:
                load_models(job)
            except GarageError as exc:
                raise GarageError(str(exc), where) from None
        else:
            _probe_error(lambda: load_models(job), where)
    shots = [len(job.setup.shots) for _, job in prepared if job.setup is not None]  # a dry run has none
    space = dataclasses.replace(space, fewest_frames=min(shots, default=0), most_frames=max(shots, default=0))
    _CHECKED[arguments] = space
    return space


def _probe(compositions: Compositions, point: list[str], where: str):
    """One point of the space composed and checked as its trial's job would be, its models not loaded: the
    preflight's PreparedJob; GarageError naming `where` when a value is wrong on its own; core.errors.Infeasible
    as it is (the point's values together are)."""
    from garage_exp.run.preflight import preflight

    return _probe_error(lambda: preflight(compositions.compose(point), check_space=False, load=False), where)


def _probe_error(check, where: str):
    """`check()`'s result; its input error as a GarageError naming `where` (Infeasible as it is)."""
    from garage_exp.core.errors import Infeasible
    from garage_exp.core.exits import input_error

    try:
        return check()
    except Infeasible:
        raise
    except GarageError as exc:
        raise GarageError(str(exc), where) from None
    except Exception as exc:
        text = input_error(exc)
        if text is None:
            raise
        raise GarageError(text, where) from None


def _check_objective(search, job: DictConfig) -> None:
    """The composed job is what the objective needs (objectives.py: a driving ego for late, a slot case on a
    fisheye rig for slots)."""
    why = objective(search.objective).needs(job)
    if why:
        raise GarageError(why, "search.objective")


def study_name_of(config: DictConfig) -> str:
    return study_mod.study_name(config.search, arguments_of(config))


def study_lock(config: DictConfig):
    """The lock beside a sqlite study (see loop.ask_lock): workers starting together open one parent run."""
    return study_mod.storage_lock(study_mod.storage_url(config.search))


def budget(search, space: space_mod.Space, study) -> int:
    """How many trials the study holds at the end: `search.trials`; a grid (sampler=grid) all its cells; a
    Saltelli design (sampler=saltelli) enqueues N x (D + 2) trials and takes as many as it needs."""
    if search.sampler == "grid":  # the whole grid, whatever search.trials says
        return study_mod.grid_size(space.params, int(search.grid_levels))
    if search.sampler != "saltelli":
        return int(search.trials)
    from garage_exp.report.sensitivity import saltelli_design

    if not study.get_trials(deepcopy=False):
        design = saltelli_design(space.params, int(search.saltelli_n), seed_of(search, None))
        for k, params in enumerate(design):
            study.enqueue_trial(params, user_attrs={"saltelli": k})
        log.info("saltelli: %d trials enqueued (N=%d)", len(design), search.saltelli_n)
    return max(int(search.trials), sum(1 for t in study.get_trials(deepcopy=False) if "saltelli" in t.user_attrs))


def seed_of(search, config: DictConfig | None) -> int:
    if search.seed is not None:
        return int(search.seed)
    return int(config.seed) if config is not None else 0


def run(config: DictConfig, loader, launch, stop=lambda: False) -> dict:
    """Run (or continue) the command's study; returns what the sweep leaves: study name, storage, trials run."""
    search = config.search
    space = check(config, loader)
    name = study_name_of(config)
    seed = seed_of(search, config)
    study = study_mod.open_study(search, name, seed, space.params)
    study.set_user_attr("command", " ".join(arguments_of(config)))
    study.set_user_attr("argv", arguments_of(config))  # as typed: a value with a space stays one argument
    # the cells its trials are described by (search.descriptors), for whoever counts them later
    study.set_user_attr("descriptors", OmegaConf.to_container(search.descriptors, resolve=True))
    store = tracked_in(config)
    total = budget(search, space, study)
    held = len(study.get_trials(deepcopy=False))
    frames = f" or {int(search.frames)} rendered frames" if int(search.get("frames") or 0) > 0 else ""
    print(f"garage_exp: study {name!r} in {study_mod.storage_url(search)}: {held} trial(s) held, up to {total}"
          f"{frames}")
    say_moved(study, name, store)
    from garage_exp.search.loop import SearchLoop

    until = _suite_full(search, stop) if search.mode == "suite" else (lambda _study: stop())
    compose = getattr(launch, "compose", None) or (lambda overrides: loader.load_sweep_config(config, overrides))
    loop = SearchLoop(search, space, study, launch, total, stop=until, compose=compose,
                      attrs={"tracking_uri": store}, plain=getattr(launch, "plain", None))
    ran = loop.run()
    return {"study": study, "name": name, "ran": ran, "space": space}


def tracked_in(config: DictConfig) -> str:
    """The tracking store this command's runs go to (tracking.uri, else $MLFLOW_TRACKING_URI, else the project's)."""
    from garage_exp.tracking import runs as tracking

    return tracking.tracking_uri(config.tracking.uri)


def say_moved(study, name: str, store: str) -> None:
    """A study continued under another tracking store than its earlier trials' (the study's storage is shared,
    MLflow's is not): it goes on, with a parent run of its own in this store (callbacks: the parent is found by
    the study's name, in this store); the earlier trials' runs stay where they are (each trial records its
    store). Said in one line; the study records the store it was last tracked in."""
    from garage_exp.tracking import runs as tracking

    tracked = [t for t in study.get_trials(deepcopy=False) if t.user_attrs.get("run_id")]
    elsewhere = sorted({u for u in {t.user_attrs.get("tracking_uri") for t in tracked} if u and u != store})
    unrecorded = [t for t in tracked if "tracking_uri" not in t.user_attrs]  # trials made before they said
    if not elsewhere and unrecorded and not run_here(tracking.client(store), unrecorded[-1].user_attrs["run_id"]):
        elsewhere = ["another store"]
    if elsewhere:
        print(f"garage_exp: study {name!r} was tracked in {', '.join(elsewhere)}; it continues tracked in {store}, "
              "with a parent run there: its earlier trials' runs stay where they were (the report and ranking "
              "cover every trial)")
    study.set_user_attr("tracking_uri", store)


def collect(config: DictConfig, loader, ran: list[int]) -> dict:
    """What `run` returns, for a study that other workers (Ray tasks, garage_exp.cluster) filled."""
    search = config.search
    space = check(config, loader)
    name = study_name_of(config)
    study = study_mod.open_study(search, name, seed_of(search, config), space.params)
    return {"study": study, "name": name, "ran": ran, "space": space}


def _suite_full(search, stop):
    """A suite's search stops early once every band holds its K scenarios."""
    from garage_exp.search.suite import bands_full

    return lambda study: stop() or bands_full(study, search)


def finish(config: DictConfig, result: dict, out_dir: Path, loader, launch) -> list[Path]:
    """The study's analysis (and suite) into out_dir; returns the files to log on the parent run."""
    from optuna.trial import TrialState

    from garage_exp.report.search_analysis import analyse
    from garage_exp.search import archive

    search = config.search
    if search.get("descriptors") and objective(search.objective).confidence:  # the report writes the archive
        archive.record(result["study"], search)
    paths = list(analyse(result["study"], out_dir, top=int(search.top)))
    if (out_dir / "archive.csv") in paths:  # its numbers for the parent run and the summary
        result["archive"] = archive.summary(result["study"].get_trials(deepcopy=False, states=(TrialState.COMPLETE,)),
                                            search)
    if search.get("runs", "per_trial") == "per_search":  # the trials have no runs: their rows go on the parent
        paths.extend(scenario_rows(result["study"], out_dir / "scenarios.csv"))
    if config.export.openscenario:
        paths.extend(export_hardest(config, result["study"], out_dir / "openscenario", loader))
    if search.mode == "suite":
        from garage_exp.search.suite import write_suite

        paths.extend(write_suite(config, result["study"], loader, launch, result["name"]))
    return paths


def scenario_rows(study, path: Path) -> list[Path]:
    """Every trial's frame rows in one table (its `trial` column first), read from the trials' own frame tables:
    what a search without a run per trial (`search.runs=per_search`) logs on its parent run; [] when no trial
    scored a frame."""
    import pandas as pd

    tables = []
    for trial in study.get_trials(deepcopy=False):
        table = Path(str(trial.user_attrs.get("output_dir") or "")) / "frames.csv"
        if trial.user_attrs.get("output_dir") and table.is_file():
            rows = pd.read_csv(table)
            tables.append(rows.assign(trial=trial.number)[["trial", *rows.columns]])
    if not tables:
        return []
    path.parent.mkdir(parents=True, exist_ok=True)
    pd.concat(tables, ignore_index=True).to_csv(path, index=False)
    return [path]


def export_hardest(config: DictConfig, study, out: Path, loader) -> list[Path]:
    """The `search.top` hardest trials as OpenSCENARIO and OpenDRIVE: out/rank<k>_trial<n>/ (each trial's job
    composed again and prepared, not rendered); [out], a folder logged as one, or [] when no trial completed."""
    from garage_exp.run.openscenario import export

    best = ranked(study)[: int(config.search.top)]
    for rank, trial in enumerate(best, start=1):
        overrides = [o for o in trial.user_attrs.get("overrides", []) if not o.startswith("search.trial=")]
        export(loader.load_sweep_config(config, overrides), out / f"rank{rank}_trial{trial.number}")
    return [out] if best else []


def log_on_parent(config: DictConfig, parent_run_id: str, result: dict, paths: list[Path], out_dir: Path) -> None:
    """The parent run of the study: the analysis, the plan's map, the study's name and storage, and the best
    trials' runs tagged with their rank."""
    from garage_exp.tracking import runs as tracking
    from garage_exp.plan.draw import draw_map
    from garage_exp.run.preflight import classified_plan, resolve_plan_path

    mlc = tracking.client(config.tracking.uri)
    study = result["study"]
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [*paths, draw_map(classified_plan(resolve_plan_path(config.plan)), out_dir / "plan_map.png")]
    for path in paths:
        if path.is_dir():  # a folder of files (the OpenSCENARIO exports) keeps its layout
            tracking.retry(lambda p=path: mlc.log_artifacts(parent_run_id, str(p), f"search/{p.name}"))
        else:
            tracking.retry(lambda p=path: mlc.log_artifact(parent_run_id, str(p), "search"))
    tags = {"study": result["name"], "storage": study_mod.storage_url(config.search),
            "search_sampler": config.search.sampler, "search_mode": config.search.mode}
    for key, value in tags.items():
        tracking.retry(lambda k=key, v=value: mlc.set_tag(parent_run_id, k, v))
    best = ranked(study)
    store = tracked_in(config)
    for rank, trial in enumerate(best[: int(config.search.top)], start=1):
        run_id = trial.user_attrs.get("run_id")
        if run_id and trial.user_attrs.get("tracking_uri", store) == store and run_here(mlc, run_id):
            tracking.retry(lambda r=run_id, k=rank: mlc.set_tag(r, "search_rank", str(k)))
    for key, value in (result.get("archive") or {}).items():  # coverage and QD score (search/archive.py)
        tracking.retry(lambda k=key, v=value: mlc.log_metric(parent_run_id, k, float(v)))
    accepted = acceptance(study)
    if accepted is not None:  # the space's requirements (search/require.py): the share of draws they kept
        tracking.retry(lambda: mlc.log_metric(parent_run_id, "acceptance_rate", accepted[0] / max(accepted[1], 1)))
    if best:  # named by the objective: best_difficulty, best_lateness, best_slot_miss
        metric = f"best_{objective(config.search.objective).metric}"
        tracking.retry(lambda: mlc.log_metric(parent_run_id, metric, float(best[0].values[0])))


def run_here(mlc, run_id: str) -> bool:
    """Whether this store holds the run: a trial made before trials recorded their store (or by a worker of
    another store) may have its run elsewhere, and tagging it would fail with "Run with id=... not found"."""
    from mlflow.exceptions import MlflowException
    from mlflow.protos.databricks_pb2 import RESOURCE_DOES_NOT_EXIST, ErrorCode

    from garage_exp.tracking import runs as tracking

    try:
        tracking.retry(lambda: mlc.get_run(run_id))
    except MlflowException as exc:
        if exc.error_code == ErrorCode.Name(RESOURCE_DOES_NOT_EXIST):
            return False
        raise
    return True


def summary(result: dict, out_dir: Path) -> str:
    """What the study holds at the end, for stdout: its trials by state and its hardest fair scenario."""
    from collections import Counter

    study = result["study"]
    states = Counter("SCREENED_EASY" if t.user_attrs.get("screened") == "easy" else
                     "REJECTED" if "rejected" in t.user_attrs else t.state.name
                     for t in study.get_trials(deepcopy=False))
    counts = ", ".join(f"{n} {s.lower().replace('pruned', 'infeasible').replace('_', ' ')}"
                       for s, n in sorted(states.items()))
    lines = [f"garage_exp: study {result['name']!r}: {sum(states.values())} trials ({counts}); "
             f"{result.get('who', 'this worker')} ran {len(result['ran'])}"]
    best = ranked(study)
    if best:
        top = best[0]
        searched = " ".join(o for o in top.user_attrs.get("overrides", []) if o.split("=")[0] in top.params)
        name = (study.user_attrs.get("direction_names") or ["difficulty"])[0]
        lines.append(f"  hardest fair scenario: trial {top.number}, {name} {top.values[0]:.3f}: {searched}")
    numbers = result.get("archive")
    if numbers:
        lines.append(f"  archive: {numbers['archive_failure_cells']} of {numbers['archive_cells']} cells hold a "
                     f"hard-and-fair failure ({numbers['archive_filled']} filled, QD score "
                     f"{numbers['archive_qd_score']:.2f}): {out_dir / 'archive.csv'}")
    accepted = acceptance(study)
    if accepted is not None:
        lines.append(f"  requirements: {accepted[0]} of {accepted[1]} draws accepted "
                     f"({100.0 * accepted[0] / max(accepted[1], 1):.0f} %), the rest redrawn before rendering")
    lines.append(f"  report: {out_dir / 'search_report.md'}")
    return "\n".join(lines)


def acceptance(study) -> tuple[int, int] | None:
    """(accepted, drawn) by the space's requirements over the study's finished draws (search/require.py); None
    when no draw was checked."""
    from optuna.trial import TrialState

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL))
    checked = [t for t in done if "rejected" in t.user_attrs or "require_estimate" in t.user_attrs]
    if not checked:
        return None
    rejected = sum("rejected" in t.user_attrs for t in checked)
    return len(checked) - rejected, len(checked)


def count_others_apart(config: DictConfig, result: dict, sweep_dir: Path) -> None:
    """The study's trials this command did not run (finished before a resume, or by another worker), recorded as
    the sweep's skipped runs, so that the sweep summary counts as finished only what this command ran, as the
    study's line does ("this worker ran 0", then "8 finished": issue 47, item 7). Only runs in this store: the
    summary reads them there."""
    from garage_exp.tracking import runs as tracking

    ran, store = set(result["ran"]), tracked_in(config)
    for t in result["study"].get_trials(deepcopy=False):
        run_id = t.user_attrs.get("run_id")
        if run_id and t.number not in ran and t.user_attrs.get("tracking_uri") == store:
            tracking.add_resumed(sweep_dir, run_id)


def trials_summary(result: dict) -> tuple[str, int]:
    """The sweep's summary when its trials have no runs (`search.runs=per_search`): how this worker's trials ended,
    from the study (one line per failed trial), and how many failed (the command's exit code counts them)."""
    from optuna.trial import TrialState

    ran = set(result["ran"])
    trials = [t for t in result["study"].get_trials(deepcopy=False) if t.number in ran]
    failed = [t for t in trials if t.state == TrialState.FAIL]
    lines = [f"garage_exp: sweep summary: {len(trials)} trials in one MLflow run (search.runs=per_search): "
             f"{len(trials) - len(failed)} finished, {len(failed)} failed"]
    lines += [f"  FAILED: trial {t.number}: {t.user_attrs.get('error') or 'no error recorded'}"[:600] for t in failed]
    return "\n".join(lines), len(failed)


def ranked(study) -> list:
    """The complete trials, hardest first (by the first value, at the end its direction calls hard; ties by
    trial number)."""
    from optuna.study import StudyDirection
    from optuna.trial import TrialState

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    sign = -1.0 if study.directions[0] == StudyDirection.MAXIMIZE else 1.0
    return sorted(done, key=lambda t: (sign * t.values[0], t.number))
