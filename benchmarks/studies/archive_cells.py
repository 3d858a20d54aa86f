"""Does the archive find more kinds of failure? Failure cells covered by the archive sampler against TPE and
random at the same number of trials (issue 39, goal 1).

Each arm is one search through the command line (`python -m garage_exp -m hydra/sweeper=search`) over the loop's
shipped space (conf/loop.yaml: two plans, cases 1, 2, 3 and pedestrian, four lights, the seed), against the loop's
D0 (the float yolo11n rebuilt from the shipped INT8 export, at 320, threshold 0.5), with fewer frames than the loop
(the black target only; the loop's 2 m steps) so that the nine searches fit on a shared 2-core machine. Every trial's
descriptors are measured by the search itself whatever its sampler (search/archive.py), so each arm's failure
cells are counted the same way: cells of the shipped descriptors (81) whose hardest trial has difficulty >= 0.6.

Run: .venv/bin/python -m benchmarks.studies.archive_cells [--trials 30] [--seeds 0,1,2] [--workers 2]
     [--samplers archive,tpe,random] [--out outputs/benchmarks/<page>]
     [--space wide] [--extra 'key=value ...'] [--page archive_cells] [--recount] [--figure PATH]
`--space NAME` searches a shipped space (conf/space/NAME.yaml: one-shot scenarios, `search.trials` of them, its
requirements redrawing what could not be fair, and its archive emitter: the wide space's surrogate since
2026-12-07) instead of the loop's; `--extra` adds overrides to every search (the descriptors, a detector,
`search.archive.emitter=gaussian` for the wide space's pages measured before); each search's own cells are counted
with the descriptors it measured.
Writes benchmarks/results/<page>.md (the table, the command, commit, date and machine), with each search's curve:
its failure cells after its first 30, 60, 125, 250, 500, 1000 ... scenarios (the order it rendered them), so that
one run shows whether a sampler overtakes another and where. `--recount` writes the page from the studies already in
`--out` (a finished or interrupted run) without running a search; `--figure PATH` draws the curves (one line a
search, the samplers' means bold).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from benchmarks.common import RESULTS, ROOT, child_env, write_json_page

SPACE = ["plan=choice(research,realistic)", "case=choice('1','2','3',pedestrian)",
         "light=choice(bright,clear,moderate,dim)", "seed=int(interval(0,9999))"]
FEWER_FRAMES = ["case.motion.step=2.0", "palette.target_colours=[black]"]  # the loop's step; one target colour
D0 = ["detector.models=[" + str(ROOT.parent / "shared" / "models" / "yolo11n_fp32_from_int8.pt") + "]",
      "detector.imgsz=320", "detector.threshold=0.5"]


def arm(out: Path, sampler: str, seed: int, trials: int, space: str = "", extra: list[str] = ()) -> dict:
    """One search; its study's failure cells and failing trials."""
    name = f"{sampler}-{seed}"
    searched = [f"space={space}"] if space else [*SPACE, *FEWER_FRAMES]
    args = [sys.executable, "-m", "garage_exp", "-m", "hydra/sweeper=search", f"search.sampler={sampler}",
            f"search.seed={seed}", f"search.trials={trials}", f"search.study=cells-{name}",
            f"search.storage=sqlite:///{out / 'optuna.db'}", f"tracking.uri=sqlite:///{out / 'mlflow.db'}",
            f"hydra.sweep.dir={out / name}", *searched, *D0, *extra]
    start = time.monotonic()
    done = subprocess.run(args, cwd=out, env=child_env(), capture_output=True, text=True)
    (out / f"{name}.log").write_text(done.stdout + done.stderr)
    return {"sampler": sampler, "seed": seed, "rc": done.returncode, "wall_s": round(time.monotonic() - start),
            **count(out, f"cells-{name}")}


CHECKPOINTS = (30, 60, 125, 250, 500, 750, 1000, 1250, 1500, 2000, 3000, 5000)


def count(out: Path, study_name: str) -> dict:
    import optuna
    from omegaconf import OmegaConf
    from optuna.trial import TrialState

    from garage_exp.search import archive
    from garage_exp.search.schema import SearchConf

    search = OmegaConf.structured(SearchConf)
    study = optuna.load_study(study_name=study_name, storage=f"sqlite:///{out / 'optuna.db'}")
    if study.user_attrs.get("descriptors"):  # the cells the search itself measured (its search.descriptors)
        from garage_exp.search.schema import DescriptorConf

        search.descriptors = [DescriptorConf(**d) for d in study.user_attrs["descriptors"]]
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    numbers = archive.summary(done, search)
    failing = sum(1 for t in done if t.values[0] >= float(search.archive.failure))
    rejected = sum(1 for t in study.trials if "rejected" in t.user_attrs)
    scenarios = len(study.trials) - rejected
    return {"trials": scenarios, "rejected": rejected, "complete": len(done),
            "failing_trials": failing,
            "failure_cells": numbers["archive_failure_cells"], "filled": numbers["archive_filled"],
            "qd_score": round(numbers["archive_qd_score"], 3), "curve": curve(study.trials, search, scenarios)}


def curve(trials: list, search, scenarios: int) -> dict[int, int]:
    """Failure cells after the first n scenarios a search told (a rejected draw is no scenario), at each of
    CHECKPOINTS up to its last, and at its last."""
    from optuna.trial import TrialState

    from garage_exp.search import archive

    told = [t for t in sorted(trials, key=lambda t: t.number) if "rejected" not in t.user_attrs]
    points = [n for n in CHECKPOINTS if n < scenarios] + [scenarios]
    return {n: archive.summary([t for t in told[:n] if t.state == TrialState.COMPLETE], search)
            ["archive_failure_cells"] for n in points}


def curve_lines(rows: list[dict], samplers: list[str]) -> list[str]:
    """The samplers' mean failure cells at each checkpoint every search reached (markdown)."""
    points = sorted(set.intersection(*[set(r["curve"]) for r in rows])) if rows else []
    lines = ["| sampler | " + " | ".join(f"{n} scenarios" for n in points) + " |",
             "|---|" + "---|" * len(points)]
    for sampler in samplers:
        mine = [r for r in rows if r["sampler"] == sampler]
        if mine:
            means = [sum(r["curve"][n] for r in mine) / len(mine) for n in points]
            lines.append(f"| {sampler} | " + " | ".join(f"{m:.1f}" for m in means) + " |")
    return lines


def draw(rows: list[dict], samplers: list[str], path: Path, title: str) -> None:
    """Failure cells against scenarios told: a thin line per search, the sampler's mean bold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for k, sampler in enumerate(samplers):
        mine = [r for r in rows if r["sampler"] == sampler]
        colour = f"C{k}"
        for r in mine:
            xs = sorted(r["curve"])
            ax.plot(xs, [r["curve"][n] for n in xs], color=colour, lw=0.8, alpha=0.5)
        common = sorted(set.intersection(*[set(r["curve"]) for r in mine])) if mine else []
        if common:
            ax.plot(common, [sum(r["curve"][n] for r in mine) / len(mine) for n in common],
                    color=colour, lw=2.2, marker="o", ms=3, label=f"{sampler} (mean of {len(mine)})")
    ax.set_xscale("log")
    ax.set_xlabel("scenarios told (rendered, or refused as infeasible)")
    ax.set_ylabel("failure cells (elite difficulty >= failure)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def out_dir(out: str, page: str) -> Path:
    """Where the searches' studies go: `--out`, else a dir of the page's own. One dir for every page made each
    search resume the study of the same sampler and seed that another page's run had left there (a variant's
    seed 0 continued from the 73 trials of a pilot with other settings), and counted both as one."""
    return Path(out) if out else ROOT / "outputs" / "benchmarks" / page


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--samplers", default="archive,tpe,random")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="", help="the studies' dir (default: outputs/benchmarks/<page>)")
    parser.add_argument("--space", default="", help="a shipped space (conf/space/NAME.yaml); default: the loop's")
    parser.add_argument("--extra", default="", help="overrides added to every search, space-separated")
    parser.add_argument("--page", default="archive_cells", help="the results page's name")
    parser.add_argument("--recount", action="store_true", help="count the studies already in --out, run nothing")
    parser.add_argument("--figure", default="", help="draw the failure cells' curves to this PNG")
    args = parser.parse_args(argv)
    out = out_dir(args.out, args.page)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(s, int(k)) for k in args.seeds.split(",") for s in args.samplers.split(",")]
    if args.recount:
        rows = [{"sampler": s, "seed": k, "rc": 0, **count(out, f"cells-{s}-{k}")} for s, k in jobs]
    else:
        with ThreadPoolExecutor(args.workers) as pool:
            rows = list(pool.map(lambda job: arm(out, job[0], job[1], args.trials, args.space, args.extra.split()),
                                 jobs))
    lines = ["| sampler | seed | trials | complete | failing trials | failure cells | cells filled | QD score |",
             "|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["sampler"], r["seed"])):
        lines.append(f"| {r['sampler']} | {r['seed']} | {r['trials']} | {r['complete']} | {r['failing_trials']} | "
                     f"{r['failure_cells']} | {r['filled']} | {r['qd_score']} |")
    means = {}
    for sampler in args.samplers.split(","):
        mine = [r for r in rows if r["sampler"] == sampler]
        means[sampler] = sum(r["failure_cells"] for r in mine) / len(mine)
    lines += ["", "Mean failure cells per search: " + ", ".join(f"{s} {m:.2f}" for s, m in means.items())]
    lines += ["", "Mean failure cells after the first n scenarios of each search:", "",
              *curve_lines(rows, args.samplers.split(","))]
    print("\n".join(lines))
    if args.figure:
        draw(rows, args.samplers.split(","), Path(args.figure),
             f"Failure cells by sampler ({'space=' + args.space if args.space else 'the loop space'}, seeds {args.seeds})")
    from benchmarks.jobkit import load, machine

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    write_json_page(RESULTS / f"{args.page}.md", "Failure cells by sampler" + (f" on the {args.space} space"
                                                                           if args.space else " (issue 39, goal 1)"),
                    {"command": "python -m benchmarks.studies.archive_cells " + " ".join(
                        "DIR" if a == args.out and a else a for a in (argv or sys.argv[1:])),  # no machine path
                     "machine": machine(), "load_after": load(), "commit": commit.strip(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                     "recounted": args.recount,  # true: counted later from the studies that command's run left
                     "rows": rows, "mean_failure_cells": means, "table": lines})
    return 0 if all(r["rc"] == 0 for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
