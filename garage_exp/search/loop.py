"""The trial loop: ask Optuna for a trial, launch it as a job through Hydra's launcher, tell Optuna its result.

Trials run one after another in the sweeper's process with Hydra's basic launcher, so the renderer (compiled
shaders, cached meshes) and the detector worker (loaded models) are set up once, not per trial. A trial is a
lean job (`search.trial` set): no plan map, glTF or plot (the study's parent run holds those), one picture, its
hardest fairly visible frame.

Several workers (processes, machines) share a study through its storage: each asks for trials until the study
holds `search.trials` of them. A lock shared by the workers makes that count exact (a file lock beside a sqlite
store, an advisory lock on PostgreSQL: garage_exp.search.storage).
"""

from __future__ import annotations

import contextlib
import gc
import logging
import math
import os
import socket
import threading
import time
from dataclasses import dataclass

import optuna
from optuna.trial import TrialState

from garage_exp.core.errors import GarageError, Infeasible, Screened
from garage_exp.core.exits import SweepStopped
from garage_exp.results.summary import JobSummary
from garage_exp.search import objectives
from garage_exp.search import require as require_mod
from garage_exp.search.objectives import num
from garage_exp.search import space as space_mod
from garage_exp.search import storage as storage_mod
from garage_exp.search import study as study_mod
from garage_exp.search import writes

log = logging.getLogger("garage_exp")
WORKER = f"{socket.gethostname()}:{os.getpid()}"
COUNTED = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL, TrialState.RUNNING)


@contextlib.contextmanager
def one_blas_thread():
    """numpy's and SciPy's OpenBLAS limited to the calling thread. A trial's products are small (ground truth's
    hidden pixels per category, projections), yet OpenBLAS hands them to its worker threads, and each worker then
    spins waiting for the next call: 13 % of a one-shot search's CPU on this 2-core machine (its thread's CPU time,
    measured), the share that a second worker, lavapipe's rasterisers and the detector's process were waiting for.
    The frame rows do not change (tests/test_oneshot.py reruns a one-shot search's elites as jobs, whose OpenBLAS
    keeps its threads, to their rows)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


@dataclass
class Outcome:
    """What a trial's job returned, as the study records it."""

    state: TrialState
    values: list[float] | None
    attrs: dict


def outcome(result, objective: str) -> Outcome:
    """A trial's state and values from its job's return: the summary (run.frames.run_frames' JobSummary, or its
    flat mapping, `as_dict()`), or {"error": ...}.
    The objective judges it (objectives.py); no values -> PRUNED (infeasible): a target nobody could see, in the
    objective's sense, is untestable, not hard; nor is a scene whose sampled values put two actors in one another
    (the job refused it: core.errors.Infeasible)."""
    if isinstance(result, dict) and result.get("infeasible"):  # its values put actors in one another
        return Outcome(TrialState.PRUNED, None, {"infeasible": True, "placement": str(result["error"])[:2000],
                                                 "fair_frames": 0, "frames": 0})
    if isinstance(result, dict) and "error" not in result:
        result = JobSummary.of(result)
    if not isinstance(result, JobSummary):
        error = result.get("error") if isinstance(result, dict) else f"the job returned {result!r}"
        return Outcome(TrialState.FAIL, None, {"error": str(error)[:2000]})
    attrs = {"run_id": result.run_id, "output_dir": result.output_dir,
             "visible_fraction": float(result.visible_fraction_mean or 0.0),
             "fair_frames": int(result.fair_frames or 0), "frames": int(result.frames or 0),
             "recall": num(result.fair_recall), "confidence": num(result.fair_confidence)}
    if result.frame:
        attrs["frame"] = result.frame
    attrs.update(objectives.recorded(result))  # what the objectives declare beside their values (the late verdict)
    values = objectives.objective(objective).judge(result, attrs)
    if values is None:
        attrs["infeasible"] = True
        return Outcome(TrialState.PRUNED, None, attrs)
    return Outcome(TrialState.COMPLETE, values, attrs)


@contextlib.contextmanager
def heartbeat(study: optuna.Study, trial: optuna.Trial):
    """Record the trial's heartbeat while it runs, so that a worker that dies leaves a trial that the next
    worker (or a resume) fails instead of waiting for it forever (Optuna's heartbeat, which `optimize` runs
    itself and ask/tell leaves to us)."""
    storage = study._storage
    stop = threading.Event()

    def beat():
        while not stop.wait(study_mod.HEARTBEAT_S):
            with contextlib.suppress(Exception):
                storage.record_heartbeat(trial._trial_id)

    with contextlib.suppress(Exception):
        storage.record_heartbeat(trial._trial_id)
    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=5)


FREEZE_AT = (1, 2, 4, 8, 16, 32, 64)  # a one-shot search's trial counts after which the collector is settled
YOUNG = 10_000  # objects allocated before the collector's youngest pass, in a one-shot search (SearchLoop.settle)


class SearchLoop:
    """Runs a study's trials as jobs. `launch(overrides, job_idx)` runs one job and returns its JobReturn."""

    def __init__(self, search, space: space_mod.Space, study: optuna.Study, launch, budget: int,
                 stop=lambda study: False, compose=None, attrs: dict | None = None, plain=None):
        self.search, self.space, self.launch, self.budget = search, space, launch, budget
        self.attrs = dict(attrs or {})  # set on every trial it asks (the tracking store its run goes to)
        self.study = study_mod.lean(study, search)  # a random search's loop keeps no trial in memory
        self.stop = stop  # asked before each trial (a suite stops once its bands are full)
        self.compose = compose  # overrides -> the trial's config, for the pre-screen
        self.plain = plain  # a search's PlainDraws (search/plain_draw.py): the check's first look from plain data
        self.url = study_mod.storage_url(search)
        self.ran: list[int] = []  # trial numbers this worker ran
        # the space's requirements, checked on each draw before it is rendered (search/require.py)
        self.require = require_mod.Require.of(search.require) if search.get("require") is not None else None
        self.in_a_row = 0  # draws the requirements rejected in a row (search.require.max_draws stops a space)
        self.stale_looked = -math.inf  # when this worker last failed a dead worker's trials (fail_stale)

    def next_trials(self) -> list[optuna.Trial]:
        """Up to `search.batch` new trials, asked under the workers' lock (so their numbers follow one another),
        none once the study holds its budget."""
        with study_mod.storage_lock(self.url):
            looked = self.fail_stale()
            held = storage_mod.count_trials(self.study, COUNTED)
            if self.require is not None:  # a rejected draw is redrawn: it takes no place in the budget
                held -= storage_mod.count_trials(self.study, (TrialState.PRUNED,), attr="rejected")
            wanted = min(int(self.search.get("batch", 1)), self.budget - held)
            if wanted <= 0 and not looked:  # the study's end: no trial left running for a dead worker
                self.fail_stale(now=True)
            # a draw's 33 parameters: one transaction, not 33; the new trial not read back
            with writes.params_at_once(self.study), writes.asked_without_reading(self.study):
                return [self.study.ask(fixed_distributions=self.space.params) for _ in range(max(wanted, 0))]

    def fail_stale(self, now: bool = False) -> bool:
        """Fail a dead worker's trials (their heartbeat older than the grace period), at most once a heartbeat
        interval unless `now`; whether it looked. A trial goes stale only GRACE_S after its last beat, so looking
        at every draw found nothing sooner: it was one query of the study's running trials a draw, ~3 ms, and a
        one-shot search makes ~3.5 draws a rendered scenario. A failed trial and a running one both hold their
        place in the budget, so the count is the same either way."""
        if not now and time.monotonic() - self.stale_looked < study_mod.HEARTBEAT_S:
            return False
        optuna.storages.fail_stale_trials(self.study)
        self.stale_looked = time.monotonic()
        return True

    def run(self) -> list[int]:
        """Ask a batch, pre-screen each trial, launch the rest as one batch, tell each its outcome; until the
        budget is spent or `stop` says so (asked between batches: a suite's last batch may overfill a band).
        Linear algebra runs on this thread alone meanwhile (`one_blas_thread`)."""
        with one_blas_thread():
            return self._run()

    def _run(self) -> list[int]:
        self.settle()
        while not self.stop(self.study) and not self.frames_spent():
            trials = self.next_trials()
            if not trials:
                break
            batch = []
            for trial in trials:
                overrides = [*self.space.overrides(trial.params), f"search.trial={trial.number}"]
                # which process (node) ran it: a cluster's trials spread; written with the check's verdict
                opening = {"overrides": overrides, "worker": WORKER, **self.attrs}
                if not self.rejects(trial, overrides, opening) and not self.screened(trial, overrides):
                    batch.append((trial, overrides))
            if batch:
                self.run_batch(batch)
        return self.ran

    def frames_spent(self) -> bool:
        """Whether the study's trials rendered its budget of frames (`search.frames`; 0: no such budget)."""
        budget = int(self.search.get("frames") or 0)
        return budget > 0 and rendered_frames(self.study) >= budget

    def run_batch(self, batch: list[tuple[optuna.Trial, list[str]]]) -> None:
        """The batch's trials as one launch (each trial's number is its job's: workers sharing a sweep dir never
        share a job dir), then each told, in order."""
        trials = [trial for trial, _ in batch]
        with contextlib.ExitStack() as beats:
            for trial in trials:
                beats.enter_context(heartbeat(self.study, trial))
            try:
                numbers = [t.number for t in trials]  # the first alone when they follow one another (Hydra's API)
                consecutive = numbers == list(range(numbers[0], numbers[0] + len(numbers)))
                returns = self.launch([overrides for _, overrides in batch], numbers[0] if consecutive else numbers)
            except SweepStopped:  # a full disk, a tracking server away: no later trial could run either
                for trial in trials:
                    self.study.tell(trial, state=TrialState.FAIL)
                raise
            except Exception as exc:  # the launcher's own failure: the batch fails, the study goes on
                for trial in trials:
                    trial.set_user_attr("error", f"{type(exc).__name__}: {exc}"[:2000])
                    self.study.tell(trial, state=TrialState.FAIL)
                    log.error("trial %d failed: %s", trial.number, exc)
                return
            except BaseException:  # Ctrl-C, SIGTERM: the batch is failed, a resume asks for others
                for trial in trials:
                    self.study.tell(trial, state=TrialState.FAIL)
                raise
        for k, (trial, returned) in enumerate(zip(trials, returns)):
            try:
                result = returned.return_value  # a job that raised raises here
            except Exception as exc:  # the job's own failure: this trial fails, the study goes on
                trial.set_user_attr("error", f"{type(exc).__name__}: {exc}"[:2000])
                self.study.tell(trial, state=TrialState.FAIL)
                log.error("trial %d failed: %s", trial.number, exc)
                continue
            except BaseException:  # a stop (SweepStopped, Ctrl-C) from the job: it and the untold ones fail
                for left in trials[k:]:
                    self.study.tell(left, state=TrialState.FAIL)
                raise
            self.tell(trial, outcome(result, self.search.objective))
        self.settle()

    def settle(self) -> None:
        """A one-shot search (`search.runs=per_search`) freezes what the process holds (the renderer, the loaded
        garages, the models, the cached compositions) out of the garbage collector's full passes after trials 1,
        2, 4, ... 64: each full pass walked all of it, about 1 s every 15 one-shot trials on this machine. What
        is alive at a freeze is never collected, so it happens only those few times (a trial's leftovers at most
        seven times over). Before the first trial the youngest generation is let grow to YOUNG objects before a
        pass (Python's default: 700) and the process is collected once and frozen: a draw's composed config, its
        scene description and the like die within a trial, and with 700 they outlived two young passes, were
        promoted and piled up into a full pass every ~3 trials (62 passes, 5.9 s of a 200-scenario search's 52 s
        on the wide space; one pass, 0.1 s, now)."""
        if self.search.get("runs", "per_trial") != "per_search":
            return
        if gc.get_threshold()[0] < YOUNG:
            gc.set_threshold(YOUNG, *gc.get_threshold()[1:])
            gc.collect()  # the start's garbage is not frozen with it
            gc.freeze()
        if len(self.ran) in FREEZE_AT:
            gc.freeze()

    def tell(self, trial: optuna.Trial, out: Outcome, first: dict | None = None) -> None:
        """Tell the trial its outcome, its attributes written first (`first`, then the outcome's) in one
        transaction."""
        if out.state == TrialState.COMPLETE and self.search.get("descriptors"):
            measured = describe(out.attrs, self.search)
            if measured is not None:
                out.attrs["descriptors"] = measured
        self.set_attrs(trial, {**(first or {}), **out.attrs})  # a dozen: one transaction
        if out.state == TrialState.FAIL:
            log.error("trial %d failed: %s", trial.number, out.attrs["error"])
        with writes.told_from_its_copy(self.study, trial):
            self.study.tell(trial, out.values, state=out.state)
        self.ran.append(trial.number)
        print(line(trial.number, out, self.budget, self.search.objective))

    def set_attrs(self, trial: optuna.Trial, attrs: dict) -> None:
        """The trial's user attributes, in one transaction."""
        with writes.attrs_at_once(self.study):
            for key, value in attrs.items():
                trial.set_user_attr(key, value)

    def rejects(self, trial: optuna.Trial, overrides: list[str], opening: dict | None = None) -> bool:
        """The space's requirements on this draw, from its scene description (search/require.py): True when they
        rejected it (told PRUNED with `rejected`; the loop asks for another in its place) or when its actors
        collide (told PRUNED infeasible, as its job would have been: it counts, and is never launched). The
        placed actors are looked at first from the draw's plain settings (`plain_look`); only a draw that look
        passes is composed and its garage built.

        `opening`: the draw's own attributes (its overrides, worker, tracking store), written with the check's in
        one transaction, whatever the check decides: a draw was three transactions before its tell (the opening,
        the check's estimate, Optuna's tell), and a one-shot search makes about 3.5 draws a rendered scenario. The
        heartbeat covers the full check alone: the plain look takes a few milliseconds, less than starting the
        heartbeat's thread and writing its first beat."""
        opening = dict(opening or {})
        if self.require is None or self.compose is None:
            self.set_attrs(trial, opening)
            return False
        from garage_exp.run.preflight import preflight

        try:
            verdict = self.plain_look(overrides)  # None: the full check decides
            if verdict is None:
                with heartbeat(self.study, trial):
                    # hand: the job of an accepted (or colliding) draw takes this scene (or refusal), not building
                    # it again; screen: most rejections are decided on the placed actors, before the garage is built
                    prepared = preflight(self.compose(overrides), check_space=False, load=False, hand=True,
                                         screen=self.first_look)
                    verdict = require_mod.judge(self.require, prepared.scene, prepared.setup, prepared.spec.primary)
        except Screened as exc:
            verdict = exc.verdict
        except (KeyboardInterrupt, SystemExit):
            self.set_attrs(trial, opening)
            self.study.tell(trial, state=TrialState.FAIL)
            raise
        except Infeasible as exc:
            # Two actors in one another: its job's preflight would raise this very refusal (the scene is built from
            # the same settings) and return it to be told PRUNED infeasible (cli/app.py). Told here, it costs no
            # launch (a composed job, its checks, its run dir made and removed): ~45 % of the wide space's draws.
            self.tell(trial, outcome({"error": str(exc), "infeasible": True}, self.search.objective), first=opening)
            self.settle()
            return True
        except Exception as exc:  # noqa: BLE001 - broken: the job itself says so, in its own words
            log.debug("trial %d: requirements not checked (%s)", trial.number, exc)
            self.set_attrs(trial, opening)
            return False
        if verdict.best is not None:  # a first look's visible is an upper bound (require.first_look)
            opening["require_estimate"] = {"visible": round(verdict.best.visible, 3),
                                           "box": round(verdict.best.box_height, 1),
                                           "distance": round(verdict.best.distance, 2),
                                           "truncation": round(verdict.best.truncation, 3)}
        if not verdict.ok:
            opening["rejected"] = verdict.why
        self.set_attrs(trial, opening)
        if verdict.ok:
            self.in_a_row = 0
            return False
        self.in_a_row += 1
        with writes.told_from_its_copy(self.study, trial):
            self.study.tell(trial, state=TrialState.PRUNED)
        print(f"garage_exp: draw {trial.number + 1}: rejected by the space's requirements ({verdict.why}); redrawn")
        if self.in_a_row >= self.require.max_draws:
            raise GarageError(f"the space's requirements rejected {self.in_a_row} draws in a row (the last: "
                              f"{verdict.why}): loosen them or the space", "search.require")
        return True

    def plain_look(self, overrides: list[str]):
        """The first look from the draw's plain settings, without composing its config (search/plain_draw.py):
        its rejection, or None when the full check decides (the look passed, or the draw could not be made there).
        Raises Infeasible as the full check would. Any other failure leaves it to the full check, whose words a
        broken draw then gets."""
        if self.plain is None:
            return None
        from garage_exp.search import plain_draw

        try:
            return plain_draw.first_look(self.plain, overrides, self.require)
        except Infeasible:
            raise
        except Exception as exc:  # noqa: BLE001 - the full check says what is wrong, in its own words
            log.debug("plain first look not made (%s)", exc)
            return None

    def first_look(self, job, setup, cameras) -> None:
        """The requirements on the placed actors alone (require.first_look): Screened with the rejection it
        decides, the same as the built scene's judge would give."""
        from garage_exp.scene.camera import scored_camera

        verdict = require_mod.first_look(self.require, setup, cameras,
                                         scored_camera(job.camera, str(job.case.camera or "")))
        if verdict is not None:
            raise Screened(verdict)

    def screened(self, trial: optuna.Trial, overrides: list[str]) -> bool:
        """The pre-screen's cheap look (search.prescreen): True when it pruned the trial."""
        if self.search.prescreen.level == "none" or self.compose is None:
            return False
        from garage_exp.search import prescreen

        try:
            with heartbeat(self.study, trial):
                seen = prescreen.look(self.compose(overrides))
        except (KeyboardInterrupt, SystemExit):
            self.study.tell(trial, state=TrialState.FAIL)
            raise
        except Infeasible:  # the full job refuses it before rendering, and the trial is pruned
            return False
        except Exception as exc:  # noqa: BLE001 - the full job will report what is wrong with the trial
            log.warning("trial %d: pre-screen failed (%s); running it in full", trial.number, exc)
            return False
        for key, value in seen.attrs.items():
            trial.set_user_attr(key, value)
        if seen.full:
            return False
        trial.set_user_attr("screened", seen.why)
        if seen.why == "infeasible":
            trial.set_user_attr("infeasible", True)
        self.study.tell(trial, state=TrialState.PRUNED)
        self.ran.append(trial.number)
        print(f"{trial_head(trial.number, self.budget)}: pre-screen ({seen.frames} cheap frames): "
              f"{'never fairly visible: infeasible' if seen.why == 'infeasible' else 'clearly easy'}; not rendered "
              "in full")
        return True


def rendered_frames(study: optuna.Study) -> int:
    """Frames the study's finished trials rendered in all (each trial's job count; a pre-screened or infeasible
    trial rendered none in full)."""
    done = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
    return sum(int(t.user_attrs.get("frames") or 0) for t in study.get_trials(deepcopy=False, states=done))


def describe(attrs: dict, search) -> dict | None:
    """A complete difficulty trial's descriptors, measured from its own outputs (its frame table and picture:
    search/archive.py) for the archive of failure kinds; None for other objectives or a job whose directory is not
    here."""
    if not objectives.objective(search.objective).confidence:
        return None
    from garage_exp.search import archive

    try:
        return archive.measure_trial(attrs.get("output_dir"), attrs.get("frame"), search)
    except Exception as exc:  # noqa: BLE001 - bookkeeping: the trial's own outcome stands
        log.warning("descriptors of %s not measured: %s", attrs.get("output_dir"), exc)
        return None


def trial_head(number: int, budget: int) -> str:
    """A trial's line starts with its number as Optuna numbers it (from 0), the number the summary, the report,
    trials.csv, archive.csv, MLflow's `search_trial` tag and optuna-dashboard give it, then how far the study is
    (before, the line said `trial 4/8` of the trial they all call 3: issue 47, item 6)."""
    return f"garage_exp: trial {number} ({number + 1} of {budget})"


def line(number: int, out: Outcome, budget: int, objective: str) -> str:
    """A trial's line on stdout, worded by the search's objective (objectives.py), whatever the values."""
    head = trial_head(number, budget)
    if out.state == TrialState.FAIL:
        return f"{head} failed: {out.attrs['error'].splitlines()[0]}"
    goal = objectives.objective(objective)
    if out.state == TrialState.PRUNED:
        if "placement" in out.attrs:  # its values put two actors in one another (core.errors.Infeasible)
            return f"{head}: {out.attrs['placement'].split(': ', 2)[-1]}: infeasible"
        return f"{head}: {goal.infeasible(out.attrs)}"
    return f"{head}: {goal.scored(out.values, out.attrs)}"
