"""Does the archive find more kinds of failure? Failure cells covered by the archive sampler against TPE and
random at the same number of trials (issue 39, goal 1).

Each arm is one search through the command line (`python -m garage_exp -m hydra/sweeper=search`) over the loop's
shipped space (conf/loop.yaml: two plans, cases 1, 2, 3 and pedestrian, four lights, the seed), against the loop's
D0 (the float yolo11n rebuilt from the shipped INT8 export, at 320, threshold 0.5), with fewer frames than the loop
(the black target only; the loop's 2 m steps) so that the nine searches fit on a shared 2-core machine. Every trial's
descriptors are measured by the search itself whatever its sampler (search/archive.py), so each arm's failure
cells are counted the same way: cells of the shipped descriptors (81) whose hardest trial has difficulty >= 0.6.

Run: .venv/bin/python -m benchmarks.studies.archive_cells [--trials 30] [--seeds 0,1,2] [--workers 2]
     [--samplers archive,tpe,random] [--out outputs/benchmarks/archive_cells]
     [--space wide] [--extra 'key=value ...'] [--page archive_cells]
`--space NAME` searches a shipped space (conf/space/NAME.yaml: one-shot scenarios, `search.trials` of them, its
requirements redrawing what could not be fair) instead of the loop's; `--extra` adds overrides to every search
(the descriptors, a detector); each search's own cells are counted with the descriptors it measured.
Writes benchmarks/results/<page>.md (the table, the command, commit, date and machine).
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
    return {"trials": len(study.trials) - rejected, "rejected": rejected, "complete": len(done),
            "failing_trials": failing,
            "failure_cells": numbers["archive_failure_cells"], "filled": numbers["archive_filled"],
            "qd_score": round(numbers["archive_qd_score"], 3)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--samplers", default="archive,tpe,random")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=str(ROOT / "outputs" / "benchmarks" / "archive_cells"))
    parser.add_argument("--space", default="", help="a shipped space (conf/space/NAME.yaml); default: the loop's")
    parser.add_argument("--extra", default="", help="overrides added to every search, space-separated")
    parser.add_argument("--page", default="archive_cells", help="the results page's name")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(s, int(k)) for k in args.seeds.split(",") for s in args.samplers.split(",")]
    with ThreadPoolExecutor(args.workers) as pool:
        rows = list(pool.map(lambda job: arm(out, job[0], job[1], args.trials, args.space, args.extra.split()), jobs))
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
    print("\n".join(lines))
    from benchmarks.jobkit import load, machine

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    write_json_page(RESULTS / f"{args.page}.md", "Failure cells by sampler" + (f" on the {args.space} space"
                                                                           if args.space else " (issue 39, goal 1)"),
                    {"command": "python -m benchmarks.studies.archive_cells " + " ".join(argv or sys.argv[1:]),
                     "machine": machine(), "load_after": load(), "commit": commit.strip(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                     "rows": rows, "mean_failure_cells": means, "table": lines})
    return 0 if all(r["rc"] == 0 for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
