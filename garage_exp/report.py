"""The sweep report: which factor makes perception hard. Main effects and pairwise effects of every swept
factor on the composite confidence and recall, a heat map, and the runs ranked by difficulty.

Runs at the end of a multirun (Hydra callback) and, for any past sweep, from the command line:
    python -m garage_exp.report                # the latest sweep
    python -m garage_exp.report --parent RUN_ID
"""

from __future__ import annotations

import argparse
import itertools
import sys
import tempfile
from pathlib import Path

import pandas as pd

from garage_exp import tracking

METRICS = ("confidence_mean", "recall", "difficulty", "visible_fraction_mean")
# Per-job mean confidence per label (colour, placement), per model and, in scenes with people, per target kind.
BREAKDOWNS = ("label.", "model.", "kind.")


def parse_overrides(text: str) -> dict[str, str]:
    out = {}
    for token in (text or "").split():
        key, eq, value = token.partition("=")
        if eq:
            out[key.lstrip("+~")] = value.strip("'\"")
    return out


def child_runs(mlc, parent_run_id: str, resumed: list[str] = ()) -> pd.DataFrame:
    """The sweep's runs: its children plus the finished runs a resumed sweep skipped."""
    parent = mlc.get_run(parent_run_id)
    runs = tracking.retry(lambda: mlc.search_runs(
        [parent.info.experiment_id], filter_string=f"tags.mlflow.parentRunId = '{parent_run_id}'",
        max_results=10000))
    known = {r.info.run_id for r in runs}
    runs = list(runs) + [tracking.retry(lambda r=r: mlc.get_run(r)) for r in resumed if r not in known]
    runs.sort(key=lambda r: r.info.start_time or 0)  # the sweep's own order, for the tables' columns
    skipped = set(resumed)
    rows = []
    for r in runs:
        row = {"run_id": r.info.run_id, "run_name": r.data.tags.get("mlflow.runName", ""), "status": r.info.status,
               "skipped": r.info.run_id in skipped, "error": r.data.tags.get("error", "")}
        row.update({f"factor.{k}": v for k, v in parse_overrides(r.data.tags.get("overrides", "")).items()})
        row.update({m: r.data.metrics.get(m) for m in METRICS})
        row.update({m: v for m, v in r.data.metrics.items() if m.startswith(BREAKDOWNS)})
        rows.append(row)
    return pd.DataFrame(rows)


def factors_of(runs: pd.DataFrame) -> list[str]:
    cols = [c for c in runs.columns if c.startswith("factor.")]
    return [c for c in cols if runs[c].nunique(dropna=True) > 1]


def main_effects(runs: pd.DataFrame, factors: list[str]) -> pd.DataFrame:
    parts = []
    for f in factors:
        g = runs.groupby(f)[["confidence_mean", "recall", "difficulty"]].mean().reset_index()
        g.insert(0, "factor", f.removeprefix("factor."))
        parts.append(g.rename(columns={f: "level"}))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def pair_effects(runs: pd.DataFrame, factors: list[str]) -> pd.DataFrame:
    parts = []
    for a, b in itertools.combinations(factors, 2):
        g = runs.groupby([a, b])[["confidence_mean", "recall"]].mean().reset_index()
        g.insert(0, "pair", f"{a.removeprefix('factor.')} x {b.removeprefix('factor.')}")
        parts.append(g.rename(columns={a: "level_a", b: "level_b"}))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def breakdown(runs: pd.DataFrame, factors: list[str], prefix: str) -> pd.DataFrame:
    """Mean composite confidence per label (or model) for every combination of the swept factors' levels:
    the research's tables (colour x light preset, placement x light) come out of a sweep as they are."""
    cols = sorted(c for c in runs.columns if c.startswith(prefix))
    if not cols or runs.empty:
        return pd.DataFrame()
    long = runs.melt(id_vars=factors, value_vars=cols, var_name="what", value_name="confidence").dropna(
        subset=["confidence"])
    long["what"] = long["what"].str.removeprefix(prefix)
    if not factors:
        return long.groupby("what")[["confidence"]].mean()
    long["levels"] = long[factors].astype(str).apply(
        lambda r: ", ".join(f"{f.removeprefix('factor.')}={v}" for f, v in r.items()), axis=1)
    return long.pivot_table(index="what", columns="levels", values="confidence", aggfunc="mean", sort=False)


def heatmaps(runs: pd.DataFrame, factors: list[str], path: Path) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = list(itertools.combinations(factors, 2))
    if not pairs or runs.empty:  # a dry-run sweep has no confidences to map
        return None
    fig, axes = plt.subplots(1, len(pairs), figsize=(4.8 * len(pairs), 4), dpi=110, squeeze=False)
    for ax, (a, b) in zip(axes[0], pairs):
        table = runs.pivot_table(index=a, columns=b, values="confidence_mean", aggfunc="mean")
        im = ax.imshow(table.to_numpy(dtype=float), vmin=0, vmax=1, cmap="viridis")
        ax.set_xticks(range(len(table.columns)), table.columns)
        ax.set_yticks(range(len(table.index)), table.index)
        ax.set_xlabel(b.removeprefix("factor."))
        ax.set_ylabel(a.removeprefix("factor."))
        for (y, x), v in pd.DataFrame(table.to_numpy()).stack().items():
            ax.text(x, y, f"{v:.2f}", ha="center", va="center", color="white" if v < 0.6 else "black", fontsize=8)
        fig.colorbar(im, ax=ax, shrink=0.8, label="mean composite confidence")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def markdown(runs: pd.DataFrame, effects: pd.DataFrame, pairs: pd.DataFrame,
             tables: dict[str, pd.DataFrame] | None = None) -> str:
    def table(df: pd.DataFrame) -> str:
        if df.empty:
            return "(none)\n"
        cols = list(df.columns)
        lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for _, r in df.iterrows():
            lines.append("| " + " | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in r) + " |")
        return "\n".join(lines) + "\n"

    failed = runs[runs.status != "FINISHED"] if "status" in runs else runs.iloc[0:0]
    ranked = runs[runs.status == "FINISHED"].sort_values("difficulty", ascending=False)
    skipped = runs[runs.skipped] if "skipped" in runs else runs.iloc[0:0]
    text = ["# Sweep report\n", f"{len(runs)} runs, {len(failed)} not finished, {len(skipped)} skipped "
            "(finished before, resume=true).\n",
            "## Main effects (mean over the other factors)\n", table(effects),
            "## Pairs\n", table(pairs),
            "## Runs ranked by difficulty (1 - mean composite confidence)\n",
            table(ranked[["run_name", "confidence_mean", "recall", "difficulty"]])]
    for title, df in (tables or {}).items():
        if not df.empty:
            text += [f"## {title}\n", table(df.reset_index())]
    if len(failed):
        text += ["## Failed runs\n", table(failed[["run_name", "status", "error"]])]
    if len(skipped):
        text += ["## Skipped (finished before)\n", table(skipped[["run_name", "run_id"]])]
    return "\n".join(text)


def summary(runs: pd.DataFrame, expected: int | None = None) -> tuple[str, int]:
    """The sweep's summary for the terminal: counts, then one line per failed run. Returns (text, number of
    failed or missing jobs). `expected`: the number of jobs launched, when known (a job without any run,
    e.g. refused for bad input in a worker, counts as failed)."""
    n = len(runs)
    if n:
        done = runs.status == "FINISHED"
        skipped = runs.skipped if "skipped" in runs else pd.Series(False, index=runs.index)
        failed = runs[~done]
        ran = int((done & ~skipped).sum())
        n_skipped = int((done & skipped).sum())
    else:
        failed, ran, n_skipped = runs, 0, 0
    missing = max(0, (expected or 0) - n)
    total = expected if expected is not None else n
    head = (f"garage_exp: sweep summary: {total} jobs: {ran} finished, {n_skipped} skipped (finished before), "
            f"{len(failed)} failed" + (f", {missing} without a run" if missing else ""))
    lines = [head]
    for _, r in failed.iterrows():
        lines.append(f"  {r.status}: {r.run_name} (run {r.run_id}): {r.error or 'no error recorded'}"[:600])
    return "\n".join(lines), len(failed) + missing


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
        finished = runs[runs.status == "FINISHED"].dropna(subset=["confidence_mean"])
        factors = factors_of(runs)
        effects = main_effects(finished, factors)
        pairs = pair_effects(finished, factors)
        runs.to_csv(out / "runs.csv", index=False)
        effects.to_csv(out / "main_effects.csv", index=False)
        pairs.to_csv(out / "pair_effects.csv", index=False)
        figure = heatmaps(finished, factors, out / "heatmap.png")
        tables = {"Per label: mean composite confidence (colour, placement)": breakdown(finished, factors, "label."),
                  "Per model: mean confidence": breakdown(finished, factors, "model."),
                  "Per target kind (vehicle, person): mean composite confidence": breakdown(finished, factors,
                                                                                           "kind.")}
        tables["Per label: mean composite confidence (colour, placement)"].to_csv(out / "labels.csv")
        tables["Per model: mean confidence"].to_csv(out / "models.csv")
        figures = f"\n## Figures\n\n![Mean composite confidence per pair of factors]({figure.name})\n" if figure else ""
        (out / "report.md").write_text(markdown(runs, effects, pairs, tables) + figures)
        for _, row in effects.iterrows():
            key = f"effect.{row.factor}.{row.level}".replace("/", "_")
            tracking.retry(lambda k=key, v=row.confidence_mean: mlc.log_metric(parent_run_id, k, float(v)))
        tracking.retry(lambda: mlc.log_metric(parent_run_id, "runs_failed", float((runs.status != "FINISHED").sum())))
        tracking.retry(lambda: mlc.log_metric(parent_run_id, "runs_skipped", float(runs.skipped.sum())))
    tracking.log_report(mlc, parent_run_id, out)
    return out / "report.md"


def latest_parent(mlc, experiment: str) -> str:
    exp = mlc.get_experiment_by_name(experiment)
    if exp is None:
        raise SystemExit(f"garage_exp.report: no experiment {experiment!r} in {tracking.tracking_uri()}")
    runs = mlc.search_runs([exp.experiment_id], filter_string="tags.sweep = 'parent'", max_results=1,
                           order_by=["attributes.start_time DESC"])
    if not runs:
        raise SystemExit(f"garage_exp.report: no sweep in experiment {experiment!r}")
    return runs[0].info.run_id


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m garage_exp.report", description=__doc__.splitlines()[0])
    ap.add_argument("--parent", help="the sweep's parent run id (default: the latest sweep)")
    ap.add_argument("--experiment", default="garage_exp")
    ap.add_argument("--uri", default=None, help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI or outputs/mlflow.db)")
    ap.add_argument("-o", "--out", default="outputs/reports", help="where to write the report")
    args = ap.parse_args(argv)
    mlc = tracking.client(args.uri)
    parent = args.parent or latest_parent(mlc, args.experiment)
    path = sweep_report(mlc, parent, Path(args.out) / parent)
    print(path.read_text())
    print(f"written: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
