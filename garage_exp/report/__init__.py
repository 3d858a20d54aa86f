"""The sweep report: which factor makes perception hard, and how sure we are. Main effects and pairwise effects
of every swept factor on composite confidence and recall with 95 % intervals over units (a cell's replicates,
never single frames), an ANOVA with effect sizes, detection against visibility, figures, and the runs ranked by
difficulty.

Runs at the end of a multirun (Hydra callback) and, for any past sweep, from the command line:
    python -m garage_exp.report                # the latest sweep
    python -m garage_exp.report --parent RUN_ID
"""

from __future__ import annotations

import argparse
import re
import tempfile
from pathlib import Path

import pandas as pd

from garage_exp.core import shell
from garage_exp.core.errors import GarageError
from garage_exp.results import stats
from garage_exp.slots import report as slots
from garage_exp.tracking import runs as tracking
from garage_exp.report import plots, visibility
from garage_exp.report.tables import (breakdown, by_camera, child_runs, factors_of, late_table, main_effects,
                                      markdown_table, number, pair_effects, parse_overrides, pivot, significance,
                                      significance_text, summary, units, with_ci)

__all__ = ["child_runs", "factors_of", "main_effects", "markdown", "pair_effects", "parse_overrides",
           "summary", "sweep_report", "latest_parent", "main"]
BREAKDOWN_TITLES = {"label": "Per label: mean composite confidence (colour, placement)",
                    "model": "Per model: mean confidence",
                    "kind": "Per target kind (vehicle, person): mean composite confidence"}


def markdown(runs: pd.DataFrame, obs: pd.DataFrame, effects: pd.DataFrame, pairs: pd.DataFrame,
             anova: pd.DataFrame, tables: dict[str, pd.DataFrame] | None = None,
             bins: pd.DataFrame | None = None, curves: pd.DataFrame | None = None,
             cameras: tuple[pd.DataFrame, pd.DataFrame] | None = None,
             slot_effects: pd.DataFrame | None = None) -> str:
    failed = runs[runs.status != "FINISHED"] if "status" in runs else runs.iloc[0:0]
    skipped = runs[runs.skipped] if "skipped" in runs else runs.iloc[0:0]
    per_cell = obs.groupby("run_id").size() if not obs.empty else pd.Series(dtype=int)
    reps = f"{per_cell.min()}" if per_cell.empty or per_cell.min() == per_cell.max() else \
        f"{per_cell.min()}-{per_cell.max()}"
    text = ["# Sweep report\n", f"{len(runs)} runs, {len(failed)} not finished, {len(skipped)} skipped "
            f"(finished before, resume=true). {len(obs)} units: {reps} replicate(s) per run.\n",
            "Intervals: 95 % percentile bootstrap over units (a run's replicates: frames of one replicate are "
            "not independent, so they are averaged first). `[-]`: one unit, no interval; `-`: no data.\n",
            "## Main effects (mean over the other factors)\n", markdown_table(effects),
            "## Significance (type-II ANOVA; partial eta squared; replicate as a block)\n",
            significance_text(anova),
            "## Pairs\n", markdown_table(pairs)]
    if not obs.empty:
        ranked = runs[runs.status == "FINISHED"][["run_id", "run_name"]].merge(
            stats.group_cis(obs, ["run_id"], ["confidence_mean", "recall"]), on="run_id")
        ranked = ranked.sort_values("confidence_mean").drop(columns="run_id")
        text += ["## Runs ranked by difficulty (lowest mean composite confidence first)\n", markdown_table(ranked)]
    for title, df in (tables or {}).items():
        if not df.empty:
            text += [f"## {title}\n", markdown_table(pivot(df).reset_index())]
    late = late_table(runs)
    if not late.empty:
        text += ["## Seen in time to stop (runs whose ego moves; docs/late.md)\n",
                 "A trajectory is late when its target, fairly visible before the critical distance, was confirmed "
                 "(k of n frames) only inside it, or never.\n", markdown_table(late)]
    if cameras is not None and not cameras[0].empty:
        first = cameras[1].pivot(index="what", columns="levels", values="first")
        text += ["## Per camera: mean composite confidence where it sees the target (best camera: the highest)\n",
                 markdown_table(pivot(cameras[0]).reset_index()),
                 "## Per camera: trajectories in which it detected the target first\n",
                 markdown_table(first[list(dict.fromkeys(cameras[1].levels))].fillna(0).astype(int).reset_index())]
    if bins is not None and not bins.empty:
        ratio = visibility.miss_rate_ratio(bins)
        text += ["## Detection against visibility (target in view; intervals over trajectories)\n",
                 markdown_table(bins),
                 f"Miss rate, heavy over reasonable (composite): "
                 f"{number(ratio) + 'x' if ratio == ratio else '- (needs misses in both bins)'} "
                 "(CityPersons: 3-4x).\n"]
    if curves is not None and not curves.empty:
        text += ["## Visible fraction at which recall crosses 0.5 (logistic fit, 95 % CI)\n",
                 markdown_table(curves.drop(columns="fit"))]
    if slot_effects is not None:
        text += slots.section(slot_effects, markdown_table, with_ci)
    if len(failed):
        text += ["## Failed runs\n", markdown_table(failed[["run_name", "status", "error"]])]
    if len(skipped):
        text += ["## Skipped (finished before)\n", markdown_table(skipped[["run_name", "run_id"]])]
    return "\n".join(text)


def sweep_report(mlc, parent_run_id: str, out_dir: str | Path | None = None, resumed: list[str] | None = None
                 ) -> Path:
    """Compute the report for the sweep under `parent_run_id`, write it to `out_dir` (a temp dir if None)
    and log it on the parent run. `resumed`: finished runs a resumed sweep skipped (kept as a parent tag)."""
    if resumed is None:
        resumed = mlc.get_run(parent_run_id).data.tags.get("resumed_runs", "").split()
    elif resumed:
        tracking.retry(lambda: mlc.set_tag(parent_run_id, "resumed_runs", " ".join(resumed)))
    runs = child_runs(mlc, parent_run_id, resumed)
    out = Path(out_dir) if out_dir else Path(tempfile.mkdtemp(prefix="garage_report_"))
    out = out / "report"
    out.mkdir(parents=True, exist_ok=True)
    if runs.empty:
        (out / "report.md").write_text("# Sweep report\n\nNo runs.\n")
    else:
        write_report(mlc, parent_run_id, runs, out)
    tracking.log_report(mlc, parent_run_id, out)
    return out / "report.md"


def write_report(mlc, parent_run_id: str, runs: pd.DataFrame, out: Path) -> None:
    factors = factors_of(runs)
    frames = visibility.frame_tables(mlc, runs)
    obs = units(runs, frames, factors)
    effects, pairs = main_effects(obs, factors), pair_effects(obs, factors)
    anova = significance(obs, factors)
    tables = {BREAKDOWN_TITLES[w]: breakdown(frames, runs, factors, w) for w in BREAKDOWN_TITLES}
    bins, curves = visibility.by_bins(frames, runs), visibility.curves(frames, runs)
    cameras = by_camera(frames, runs, factors)
    slot_obs = slots.slot_units(runs, visibility.run_tables(mlc, runs, "slots.csv"), factors)
    slot_effects = slots.slot_effects(slot_obs, factors) if not slot_obs.empty else pd.DataFrame()
    for name, df in (("runs", runs), ("units", obs), ("main_effects", effects), ("pair_effects", pairs),
                     ("anova", anova), ("labels", tables[BREAKDOWN_TITLES["label"]]),
                     ("models", tables[BREAKDOWN_TITLES["model"]]), ("visibility_bins", bins),
                     ("visibility_curve", curves.drop(columns="fit") if not curves.empty else curves),
                     ("cameras", cameras[0]), ("cameras_first", cameras[1]), ("slot_units", slot_obs),
                     ("slot_effects", slot_effects)):
        df.to_csv(out / f"{name}.csv", index=False)
    plots.heatmaps(obs, factors, out / "heatmap.png")
    plots.main_effects(effects, out / "main_effects.png")
    plots.interactions(pairs, out / "interactions.png")
    plots.visibility(visibility.in_view(frames, runs), curves, out / "visibility.png")
    text = markdown(runs, obs, effects, pairs, anova, tables, bins, curves, cameras, slot_effects)
    if not slot_effects.empty:
        text += "\n" + "\n".join(slots.pictures(mlc, slot_obs, slot_effects, out))
    figures = [p for p in ("main_effects.png", "interactions.png", "heatmap.png", "visibility.png")
               if (out / p).exists()]
    text += "\n## Figures\n\n" + "\n".join(f"![{p}]({p})" for p in figures) + "\n"
    (out / "report.md").write_text(text)
    for _, row in effects.iterrows():
        # MLflow takes letters, digits and _-. :/ in a name: a list level ([black]) becomes _black_
        key = re.sub(r"[^\w\-. :]", "_", f"effect.{row.factor}.{row.level}")
        tracking.retry(lambda k=key, v=row.confidence_mean: mlc.log_metric(parent_run_id, k, float(v)))
    tracking.retry(lambda: mlc.log_metric(parent_run_id, "runs_failed", float((runs.status != "FINISHED").sum())))
    tracking.retry(lambda: mlc.log_metric(parent_run_id, "runs_skipped", float(runs.skipped.sum())))


def latest_parent(mlc, experiment: str) -> str:
    exp = mlc.get_experiment_by_name(experiment)
    if exp is None:
        raise GarageError(f"no experiment {experiment!r}", tracking.tracking_uri())
    runs = mlc.search_runs([exp.experiment_id], filter_string="tags.sweep = 'parent'", max_results=1,
                           order_by=["attributes.start_time DESC"])
    if not runs:
        raise GarageError(f"no sweep in experiment {experiment!r}", tracking.tracking_uri())
    return runs[0].info.run_id


COMMAND = shell.Command("garage_exp.report")


def run(args: argparse.Namespace) -> int:
    mlc = tracking.existing_client(args.uri)
    parent = args.parent or latest_parent(mlc, args.experiment)
    path = sweep_report(mlc, parent, Path(args.out) / parent)
    print(path.read_text())
    print(f"written: {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """The command in the one shell (garage_exp.core.shell): bad input (no store, experiment or sweep) one line
    and 2, Ctrl-C 130, SIGTERM 143."""
    ap = argparse.ArgumentParser(prog="python -m garage_exp.report", description=__doc__.splitlines()[0])
    ap.add_argument("--parent", help="the sweep's parent run id (default: the latest sweep)")
    ap.add_argument("--experiment", default="garage_exp")
    ap.add_argument("--uri", default=None, help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI or outputs/mlflow.db)")
    ap.add_argument("-o", "--out", default="outputs/reports", help="where to write the report")
    return COMMAND.run_args(ap, run, argv)
