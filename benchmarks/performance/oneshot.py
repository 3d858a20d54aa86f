"""One-shot scenarios a second (issue 49, item 6): today's search of one-frame trials against the one-shot path,
in one run on one machine, printed as scenarios a second and their ratio.

    python -m benchmarks.performance.oneshot [--trials 400] [--today-trials 80] [--rounds 1]

Both arms run the same search, each in a child process of its own (`python -m garage_exp -m
hydra/sweeper=search`, the sweeper's in-process trials): a one-frame scenario of the lighting case (`case=light`, a
black car ahead of a static ego) at 320x240 with one INT8 detector (yolo11n), the random sampler drawing the garage
among four shipped plans (`plan=choice(small,research,realistic,obstacles)`: another garage every 1.3 scenarios on
average, more often than the issue's "at least every 32"), the light's intensity and the target's distance and
yaw. Every scenario is end to end: the draw (Optuna's ask), the scene change, render, ground truth, detection, its
frame row and the study's tell.

  today    the search as shipped: an MLflow run per trial (`search.runs=per_trial`), the last garage kept
  oneshot  `search.runs=per_search` (one MLflow run for the search, the scenarios' rows on it) and
           `renderer.kept_garages=4` (the four garages stay loaded: a switch replaces actors, rebuilds nothing)

The rate is sustained: scenarios told per second after the first `--warmup` (shaders, each garage's first load and
the detector's start are paid once per process), from the study's own clock (each trial's end). With `--rounds 2`
the arms alternate (today, oneshot, today, oneshot) so that another process's load falls on both. `--before DIR`
runs today's arm on another checkout (e.g. the commit before this benchmark) instead of this one's per_trial path;
with `--before-oneshot` that checkout's oneshot arm runs too (`oneshot@before`), so that one invocation gives both
the ratio to today's search and this checkout's gain on the one-shot path itself (with `--workers N` too, that
checkout's workers arm, `oneshot x N@before`). `--workers N` adds the
oneshot arm as N workers of one search (N children on one study's storage, as the search runs on several
machines; each draws other scenarios: the samplers seed each trial by its number): its rate counts the scenarios
told while every worker was past its warm-up and none had stopped; with `--pin` also as N workers each kept on
its own CPU (`search.cpus`, the arm `oneshot x N, pinned`). The page: benchmarks/results/oneshot.md.

`--space wide` measures the wide space instead (conf/space/wide.yaml: one-shot scenarios over 31 factors, each
draw checked against the space's requirements before it is rendered, a rejected draw redrawn), on generated garages:
`plan.seed` drawn among `--garages` seeds (16: with 400 scenarios, a garage not seen before every 25 scenarios on
average, inside the issue's "at least every 32"), the oneshot arm keeping them all loaded. Its rate counts the
scenarios told (a rejected draw costs its check, and counts as none; a draw whose actors collide is told PRUNED
infeasible without rendering, and counts), and `rendered / s` those rendered and scored alone. The page:
benchmarks/results/oneshot_wide.md.

`--side-by-side PAIRS` (with `--before DIR`) measures one checkout against another on a machine shared with others,
whose speed drifts from one minute to the next by more than a change of a few per cent: the two checkouts' one-shot
searches (one worker each) run at the same time, PAIRS times, and each pair gives the ratios of their rendered
scenarios a second and of their CPU seconds a rendered scenario; the page prints each pair and the medians
(benchmarks/results/oneshot_<space>_side_by_side.md).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import RESULTS, ROOT, child_env

PLANS = "plan=choice(small,research,realistic,obstacles)"
SCENARIO = ["case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]", "camera.width=320",
            "camera.height=240", "renderer.save_frames=none", "detector.models=[yolo11n_int8_openvino_model]"]
SPACE = [PLANS, "light.intensity=interval(0.1,1.0)", "case.actors.target.distance=interval(4.0,12.0)",
         "case.actors.target.yaw=interval(-30.0,30.0)"]
ARMS = {"today": ["search.runs=per_trial", "renderer.kept_garages=1"],
        "oneshot": ["search.runs=per_search", "renderer.kept_garages=4"]}
WIDE = ["space=wide", "camera.width=320", "camera.height=240", "renderer.save_frames=none",
        "detector.models=[yolo11n_int8_openvino_model]", "detector.imgsz=320"]


CHILD_FLAGS: list[str] = []  # what the children are told besides their arm (--space, --garages)
SAMPLER = ["random"]  # --sampler: every arm's (a search's own emitter, e.g. the surrogate's, as an override)


def use_space(name: str, garages: int) -> None:
    """The arms on a shipped space (its own scenario, factors and requirements) on `garages` generated garages."""
    global SCENARIO, SPACE
    SCENARIO = [w.replace("space=wide", f"space={name}") for w in WIDE]
    SPACE = [f"plan.seed=int(interval(0,{garages - 1}))"]
    ARMS["oneshot"] = ["search.runs=per_search", f"renderer.kept_garages={min(garages, 16)}"]


def cpu_seconds() -> tuple[float, float]:
    """CPU seconds (user + system) of this process (its render threads included) and of its children (the
    detector's process)."""
    import psutil

    me = psutil.Process()
    own = sum(me.cpu_times()[:2])
    kids = 0.0
    for kid in me.children(recursive=True):
        try:
            kids += sum(kid.cpu_times()[:2])
        except psutil.Error:
            pass
    return own, kids


def child(arm: str, trials: int, out: str, warmup: int, extra: list[str], shared: str = "") -> int:
    """One arm's search in this process; each trial's end time (and plan), and the CPU seconds at the end of the
    warm-up and of the last trial, to `out` as JSON. With `shared` (a folder), the study's storage is there, so
    that several children are several workers of one search."""
    os.environ.setdefault("YOLO_OFFLINE", "1")
    from garage_exp.cli import app
    from garage_exp.search import loop

    print(f"garage_exp from {Path(app.__file__).parent.parent}", file=sys.stderr)

    ends: list[float] = []
    told: list[str] = []  # each told trial's state, in the order of `ends` (COMPLETE: rendered and scored)
    cpu: list[tuple[float, float]] = []
    real_tell = loop.SearchLoop.tell

    def tell(self, trial, outcome, *args, **kwargs):  # a checkout's own tell may take more (its first attrs)
        real_tell(self, trial, outcome, *args, **kwargs)
        ends.append(time.perf_counter())
        told.append(outcome.state.name)
        if len(ends) == warmup:
            cpu[:] = [cpu_seconds()]

    real_run = loop.SearchLoop.run

    def run(self):  # the trial loop's end, after its last tell: not the process's (a search's end writes its report)
        ran = real_run(self)
        if len(ends) > warmup:
            cpu[1:] = [cpu_seconds()]
        return ran

    loop.SearchLoop.tell = tell
    loop.SearchLoop.run = run
    arm_overrides = ARMS[arm] if arm in ARMS else []  # a --before checkout's today knows no new keys
    with (contextlib.nullcontext(shared) if shared else tempfile.TemporaryDirectory()) as tmp:
        argv = ["-m", "hydra/sweeper=search", *SCENARIO, *SPACE, *arm_overrides, f"search.trials={trials}",
                f"search.sampler={SAMPLER[0]}", "search.seed=0", f"search.study=oneshot-{arm}",
                f"search.storage=sqlite:///{tmp}/optuna.db", f"tracking.uri=sqlite:///{tmp}/mlflow.db",
                f"hydra.sweep.dir={tmp}/sweep", "hydra/job_logging=disabled", "hydra/hydra_logging=disabled", *extra]
        start, epoch = time.perf_counter(), time.time()
        code = 0
        try:
            app.cli(argv)
        except SystemExit as exc:
            code = int(exc.code or 0)
        total = time.perf_counter() - start
        import optuna

        study = optuna.load_study(study_name=f"oneshot-{arm}", storage=f"sqlite:///{tmp}/optuna.db")
        kept = [t for t in sorted(study.trials, key=lambda t: t.number) if "rejected" not in t.user_attrs]
        plans = [t.params.get("plan", t.params.get("plan.seed")) for t in kept]
        states = [t.state.name for t in kept]
        rejected = len(study.trials) - len(kept)
    Path(out).write_text(json.dumps({"arm": arm, "code": code, "ends": [e - start for e in ends], "told": told,
                                     "total": total, "epoch": epoch,
                                     "plans": plans, "complete": states.count("COMPLETE"), "cpu": cpu,
                                     "trials": len(states), "rejected": rejected}))
    return code


def rate(ends: list[float], warmup: int) -> tuple[float, int]:
    """Scenarios a second from the end of trial `warmup` to the last one's, and how many that counts."""
    counted = len(ends) - warmup
    if counted < 2:
        return float("nan"), 0
    return counted / (ends[-1] - ends[warmup - 1]), counted


def rendered_rate(r: dict, warmup: int) -> float:
    """Scenarios rendered and scored (told COMPLETE) a second over `rate`'s span: a draw the job refused before
    rendering (two actors in one another: PRUNED infeasible) is told too, and counts in `rate`, not here."""
    ends, told = r["ends"], r.get("told") or []
    if len(ends) - warmup < 2:
        return float("nan")
    if len(told) != len(ends):  # a --before checkout's child records no states: its arm's share of complete ones
        return rate(ends, warmup)[0] * r["complete"] / max(r["trials"], 1)
    return told[warmup:].count("COMPLETE") / (ends[-1] - ends[warmup - 1])


def longest_run(plans: list) -> int:
    """The most consecutive scenarios on one garage."""
    best = run = 0
    for k, plan in enumerate(plans):
        run = run + 1 if k and plan == plans[k - 1] else 1
        best = max(best, run)
    return best


def start_child(name: str, trials: int, warmup: int, code: Path | None, extra: list[str], shared: str = ""):
    """One child's search started (not waited for): its process and the file it writes its record to."""
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
        out = fh.name
    # the file, not `-m`, from the code's own checkout: `python -m` would put the working dir first on sys.path
    # and import this checkout's garage_exp for --before's arm (as performance/before.py runs its children)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", name, "--trials", str(trials),
           "--warmup", str(warmup), "--out", out, *(["--shared", shared] if shared else []), *CHILD_FLAGS, *extra]
    proc = subprocess.Popen(cmd, cwd=code or ROOT, env=child_env(code, GARAGE_EXP_PROVISIONED="1"),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, out


def finish_children(started: list, arm: str) -> list[dict]:
    """The started children's records, once all have ended (an arm whose child failed stops the benchmark)."""
    logs = [proc.communicate()[0] for proc, _ in started]
    for (proc, _), log in zip(started, logs):
        if proc.returncode != 0:
            sys.stderr.write(log[-6000:])
            raise SystemExit(f"the {arm} arm failed (exit {proc.returncode})")
    results = [json.loads(Path(out).read_text()) for _, out in started]
    for _, out in started:
        os.unlink(out)
    return results


def run_arm(arm: str, trials: int, warmup: int, code: Path | None, extra: list[str], name: str | None = None,
            workers: int = 1, pin: bool = False) -> dict:
    """One arm: its child's search, or `workers` children sharing one study (the search's workers on one
    storage, as on a cluster), combined by `merge`; `pin`: worker k kept on CPU k (`search.cpus`, round the
    machine's CPUs)."""
    name = name or ("before" if code is not None else arm)
    shared = tempfile.mkdtemp(prefix="oneshot-shared-") if workers > 1 else ""
    load = os.getloadavg()[0]
    started = time.perf_counter()
    cpus = sorted(os.sched_getaffinity(0)) if pin else []
    results = finish_children([start_child(name, trials, warmup, code,
                                           [*extra, *([f"search.cpus={cpus[k % len(cpus)]}"] if pin else [])], shared)
                               for k in range(workers)], arm)
    wall = time.perf_counter() - started
    if shared:
        import shutil

        shutil.rmtree(shared, ignore_errors=True)
    result = results[0] if workers == 1 else merge(results, warmup)
    return {**result, "arm": arm, "wall": wall, "load_before": load, "load_after": os.getloadavg()[0],
            "workers": workers}


def side_by_side(pairs: int, trials: int, warmup: int, before: Path, extra: list[str]) -> list[dict]:
    """The one-shot path of `before` and of this checkout, one worker each, run at the same time, `pairs` times:
    on a machine shared with others, whose speed drifts by a fifth from one minute to the next here, a pair
    sees the same neighbours, so its ratio holds where consecutive arms' rates do not (`pair_row`)."""
    rows = []
    for k in range(pairs):
        load = os.getloadavg()[0]
        old, new = finish_children([start_child("oneshot", trials, warmup, before, extra),
                                    start_child("oneshot", trials, warmup, None, extra)], "side by side")
        rows.append({"pair": k + 1, **pair_row(old, new, warmup),
                     "load": f"{load:.2f} -> {os.getloadavg()[0]:.2f}"})
    return rows


def pair_row(old: dict, new: dict, warmup: int) -> dict:
    """One side-by-side pair: each side's scenarios rendered a second and its search process's CPU seconds a
    rendered scenario (after its warm-up), and this checkout's ratios to `old`'s."""
    def side(r: dict) -> tuple[float, float]:
        shown = rendered_rate(r, warmup)
        rendered = r["told"][warmup:].count("COMPLETE") if r.get("told") else 0
        cpu = (r["cpu"][1][0] - r["cpu"][0][0]) / rendered if len(r.get("cpu", [])) == 2 and rendered else float("nan")
        return shown, cpu

    (old_rate, old_cpu), (new_rate, new_cpu) = side(old), side(new)
    return {"before_rendered_per_s": round(old_rate, 3), "rendered_per_s": round(new_rate, 3),
            "rate_ratio": round(new_rate / old_rate, 3), "before_cpu": round(old_cpu, 3), "cpu": round(new_cpu, 3),
            "cpu_ratio": round(new_cpu / old_cpu, 3)}


def merge(results: list[dict], warmup: int) -> dict:
    """Several workers' records as one arm's: the scenarios told while every worker was warm (after each one's
    first `warmup`) and none had stopped, in the order they ended (their `rate` then counts from the window's
    first), with the CPU seconds of all of them over that span, per scenario they told after their warm-up."""
    lo = max(r["epoch"] + r["ends"][warmup - 1] for r in results)
    hi = min(r["epoch"] + r["ends"][-1] for r in results)
    told = sorted((r["epoch"] + e, state) for r in results for e, state in zip(r["ends"], r["told"])
                  if lo <= r["epoch"] + e <= hi)
    own = sum(r["cpu"][1][0] - r["cpu"][0][0] for r in results)
    kids = sum(r["cpu"][1][1] - r["cpu"][0][1] for r in results)
    after = sum(len(r["ends"]) - warmup for r in results)
    last = results[-1]  # each worker loaded the same shared study at its end: its counts are the study's
    return {"code": max(r["code"] for r in results), "ends": [t for t, _ in told], "told": [s for _, s in told],
            "window_warmup": 1, "cpu_per_scenario": (own / max(after, 1), kids / max(after, 1)),
            "total": max(r["total"] for r in results), "plans": last["plans"], "complete": last["complete"],
            "trials": last["trials"], "rejected": last["rejected"], "cpu": []}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=400, help="one-shot scenarios of the oneshot arm")
    parser.add_argument("--today-trials", type=int, default=80, help="scenarios of today's arm (slower)")
    parser.add_argument("--warmup", type=int, default=16, help="scenarios left out at each arm's start")
    parser.add_argument("--rounds", type=int, default=1, help="today and oneshot alternated this many times")
    parser.add_argument("--before", type=Path, default=None, help="today's arm on this checkout instead")
    parser.add_argument("--before-oneshot", action="store_true",
                        help="with --before: also its oneshot arm (oneshot@before), for this checkout's gain on it")
    parser.add_argument("--page", type=Path, default=None, help="default: results/oneshot.md (oneshot_<space>.md)")
    parser.add_argument("--space", default="", help="a shipped space (wide) on generated garages instead")
    parser.add_argument("--garages", type=int, default=16, help="with --space: generated garages drawn among")
    parser.add_argument("--sampler", default="random",
                        help="every arm's sampler (random; archive: give its emitter as an override, e.g. "
                             "search.archive.emitter=surrogate, whose draws are rejected less often)")
    parser.add_argument("--workers", type=int, default=1,
                        help="also the oneshot arm as this many workers sharing one study (oneshot x N)")
    parser.add_argument("--pin", action="store_true",
                        help="with --workers N: also those workers each kept on its own CPU (search.cpus)")
    parser.add_argument("--side-by-side", type=int, default=0, metavar="PAIRS",
                        help="with --before: instead of the arms, its one-shot path and this checkout's run at the "
                             "same time, one worker each, this many times (a ratio that holds on a shared machine)")
    parser.add_argument("--child", choices=[*ARMS, "before"], help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    parser.add_argument("--shared", default="", help=argparse.SUPPRESS)
    parser.add_argument("overrides", nargs="*", help="more Hydra overrides for both arms")
    opts = parser.parse_args()
    SAMPLER[0] = opts.sampler
    CHILD_FLAGS[:] = [f"--sampler={opts.sampler}"]
    if opts.space:
        use_space(opts.space, opts.garages)
        CHILD_FLAGS[:] += [f"--space={opts.space}", f"--garages={opts.garages}"]  # the children measure it too
    stem = f"oneshot_{opts.space}" if opts.space else "oneshot"
    page = opts.page or RESULTS / (f"{stem}_side_by_side.md" if opts.side_by_side else f"{stem}.md")
    if opts.child:
        return child(opts.child, opts.trials, opts.out, opts.warmup, opts.overrides, opts.shared)

    from benchmarks.jobkit import machine

    args = sys.argv[1:]
    if opts.before is not None:  # the page keeps no machine path: the other checkout is named by its commit below
        args = [("DIR" if a == str(opts.before) else a.replace(str(opts.before), "DIR")) for a in args]
    command = " ".join(["python -m benchmarks.performance.oneshot", *args])
    before_commit = "" if opts.before is None else subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=opts.before, capture_output=True, text=True).stdout.strip()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    if opts.side_by_side:
        if opts.before is None:
            parser.error("--side-by-side needs --before")
        return side_by_side_page(side_by_side(opts.side_by_side, opts.trials, opts.warmup, opts.before,
                                              opts.overrides), page, command, commit, before_commit)
    runs = []
    for _ in range(opts.rounds):
        runs.append(run_arm("today", opts.today_trials, opts.warmup, opts.before, opts.overrides))
        if opts.before is not None and opts.before_oneshot:
            runs.append(run_arm("oneshot@before", opts.trials, opts.warmup, opts.before, opts.overrides, "oneshot"))
        runs.append(run_arm("oneshot", opts.trials, opts.warmup, None, opts.overrides))
        if opts.workers > 1:
            if opts.before is not None and opts.before_oneshot:
                runs.append(run_arm(f"oneshot x {opts.workers}@before", opts.trials, opts.warmup, opts.before,
                                    opts.overrides, "oneshot", workers=opts.workers))
            runs.append(run_arm(f"oneshot x {opts.workers}", opts.trials, opts.warmup, None, opts.overrides,
                                "oneshot", workers=opts.workers))
            if opts.pin:
                runs.append(run_arm(f"oneshot x {opts.workers}, pinned", opts.trials, opts.warmup, None,
                                    opts.overrides, "oneshot", workers=opts.workers, pin=True))
    rows = []
    for r in runs:
        warm = r.get("window_warmup", opts.warmup)
        per_s, counted = rate(r["ends"], warm)
        if "cpu_per_scenario" in r:  # several workers: their CPU over what each told after its warm-up
            cpu_main, cpu_detector = r["cpu_per_scenario"]
        else:
            (own0, kids0), (own1, kids1) = r["cpu"] if len(r["cpu"]) == 2 else [(float("nan"),) * 2] * 2
            cpu_main, cpu_detector = (own1 - own0) / max(counted, 1), (kids1 - kids0) / max(counted, 1)
        rows.append({"arm": r["arm"], "scenarios": r["trials"], "complete": r["complete"], "counted": counted,
                     "cpu_main": round(cpu_main, 3), "cpu_detector": round(cpu_detector, 3),
                     "per_s": round(per_s, 3), "s_each": round(1 / per_s, 3), "garages": len(set(r["plans"])),
                     "rendered_per_s": round(rendered_rate(r, warm), 3),
                     "rejected": r.get("rejected", 0),
                     "longest_on_one": longest_run(r["plans"]), "wall_s": round(r["wall"], 1),
                     "load": f"{r['load_before']:.2f} -> {r['load_after']:.2f}"})
    today = [row["per_s"] for row in rows if row["arm"] == "today"]
    new = [row["per_s"] for row in rows if row["arm"] == "oneshot"]
    ratio = (sum(new) / len(new)) / (sum(today) / len(today))
    old = [row["per_s"] for row in rows if row["arm"] == "oneshot@before"]
    gain = (sum(new) / len(new)) / (sum(old) / len(old)) if old else None
    header = ("| arm | scenarios | rejected before rendering | complete | counted | scenarios / s | rendered / s | "
              "s / scenario | "
              "CPU s / scenario: search process, detector | garages | most in a row on one | child wall (s) | "
              "load (1 min) |")
    lines = ["# One-shot scenarios a second (issue 49, item 6)", "",
             f"`{command}` · commit `{commit}` · {time.strftime('%Y-%m-%d %H:%M')} · {machine()}", "",
             f"scenario: {' '.join(SCENARIO)}", f"space: {' '.join(SPACE)}; sampler: {SAMPLER[0]}", "", header,
             "|" + "---|" * 13]
    lines += [f"| {r['arm']} | {r['scenarios']} | {r['rejected']} | {r['complete']} | {r['counted']} | {r['per_s']:.2f} | "
              f"{r['rendered_per_s']:.2f} | "
              f"{r['s_each']:.3f} | {r['cpu_main']:.3f}, {r['cpu_detector']:.3f} | {r['garages']} | "
              f"{r['longest_on_one']} | {r['wall_s']} | {r['load']} |"
              for r in rows]
    verdict = "met" if min(new) >= 5.0 else "NOT met"
    cpu = min((row["cpu_main"] + row["cpu_detector"], row["cpu_main"]) for row in rows if row["arm"] == "oneshot")
    lines += ["", f"oneshot / today: **{ratio:.2f}x**; the oneshot arm sustains {min(new):.2f}-{max(new):.2f} "
              f"scenarios/s (goal >= 5: {verdict}). It used {cpu[0]:.3f} CPU s a scenario in all ({cpu[1]:.3f} in "
              f"the search's process, its render threads included): on two idle cores at most {2 / cpu[0]:.1f} "
              "scenarios/s."]
    many = [row for row in rows if row["arm"].startswith("oneshot x ") and not row["arm"].endswith("@before")]
    many_before = [row for row in rows if row["arm"].startswith("oneshot x ") and row["arm"].endswith("@before")]
    for arm in dict.fromkeys(row["arm"] for row in many):  # each workers arm: as the scheduler puts them, pinned
        best = max(row["per_s"] for row in many if row["arm"] == arm)
        shown = max(row["rendered_per_s"] for row in many if row["arm"] == arm)
        kept = ", each kept on its own CPU (search.cpus)" if arm.endswith("pinned") else ""
        lines += ["", f"{arm} (workers sharing one study, each its own renderer and detector{kept}): "
                  f"**{best:.2f}** scenarios/s sustained while all were warm, {best / (sum(today) / len(today)):.2f}x "
                  f"today, {best / (sum(new) / len(new)):.2f}x one worker (goal >= 5: "
                  f"{'met' if best >= 5.0 else 'NOT met'} as told, infeasible draws counted); rendered and scored "
                  f"alone **{shown:.2f}**/s (goal >= 5: {'met' if shown >= 5.0 else 'NOT met'})."]
    if gain is not None:
        lines += ["", f"oneshot / oneshot@before (the same one-shot path on the checkout at {before_commit}): **{gain:.2f}x**."]
    many = [row for row in many if not row["arm"].endswith("pinned")]  # the before checkout's are not pinned
    if many and many_before:
        told = max(r["per_s"] for r in many) / max(r["per_s"] for r in many_before)
        shown = max(r["rendered_per_s"] for r in many) / max(r["rendered_per_s"] for r in many_before)
        lines += ["", f"{many[0]['arm']} / {many_before[0]['arm']} (the checkout at {before_commit}): **{told:.2f}x** "
                  f"told, **{shown:.2f}x** rendered."]
    return write_page(page, lines, {"rows": rows, "ratio": ratio, "gain": gain})


def write_page(page: Path, lines: list[str], data: dict) -> int:
    """The page (its lines, then its numbers as JSON for a later run to read back), printed and written."""
    text = "\n".join([*lines, "", "```json", json.dumps(data), "```"]) + "\n"
    print(text)
    page.write_text(text)
    return 0


def side_by_side_page(rows: list[dict], page: Path, command: str, commit: str, before_commit: str) -> int:
    from statistics import median

    from benchmarks.jobkit import machine

    lines = ["# One-shot scenarios a second, two checkouts side by side (issue 49, item 6)", "",
             f"`{command}` · commit `{commit}` against `{before_commit}` · {time.strftime('%Y-%m-%d %H:%M')} · "
             f"{machine()}", "", f"scenario: {' '.join(SCENARIO)}", f"space: {' '.join(SPACE)}; sampler: {SAMPLER[0]}",
             "", "Each pair: the two checkouts' one-shot searches (one worker each) at the same time.", "",
             "| pair | rendered / s: before | this checkout | ratio | CPU s / rendered (search process): before | "
             "this checkout | ratio | load (1 min) |", "|" + "---|" * 8]
    lines += [f"| {r['pair']} | {r['before_rendered_per_s']:.2f} | {r['rendered_per_s']:.2f} | {r['rate_ratio']:.3f} | "
              f"{r['before_cpu']:.3f} | {r['cpu']:.3f} | {r['cpu_ratio']:.3f} | {r['load']} |" for r in rows]
    rate, cpu = median(r["rate_ratio"] for r in rows), median(r["cpu_ratio"] for r in rows)
    lines += ["", f"median over {len(rows)} pairs: rendered a second **{rate:.3f}x**, CPU a rendered scenario "
              f"**{cpu:.3f}x** the checkout at {before_commit}."]
    return write_page(page, lines, {"pairs": rows, "rate_ratio": rate, "cpu_ratio": cpu})


if __name__ == "__main__":
    sys.exit(main())
