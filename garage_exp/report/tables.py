"""The report's tables: the sweep's runs, their units of observation (a cell's replicates), main and pairwise
effects with 95 % intervals, the ANOVA, per-label and per-model breakdowns, and the terminal summary."""

from __future__ import annotations

import itertools
import math

import pandas as pd

from garage_exp.results import late as late_metrics
from garage_exp.results import stats
from garage_exp.tracking import runs as tracking

METRICS = ("confidence_mean", "recall", "difficulty", "visible_fraction_mean")
RESPONSES = ["confidence_mean", "recall"]
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
               "skipped": r.info.run_id in skipped, "error": r.data.tags.get("error", ""),
               "threshold": float(r.data.params.get("detector.threshold", 0.5))}
        row.update({f"factor.{k}": v for k, v in parse_overrides(r.data.tags.get("overrides", "")).items()})
        row.update({m: r.data.metrics.get(m) for m in METRICS})
        # a moving ego's verdict (results/late.py), logged by jobs whose case drives the ego
        row.update({m: r.data.metrics[m] for m in late_metrics.METRICS if m in r.data.metrics})
        row.update({m: v for m, v in r.data.metrics.items() if m.startswith(BREAKDOWNS)})
        rows.append(row)
    return pd.DataFrame(rows)


def factors_of(runs: pd.DataFrame) -> list[str]:
    cols = [c for c in runs.columns if c.startswith("factor.")]
    return [c for c in cols if runs[c].nunique(dropna=True) > 1]


def primary(frames: pd.DataFrame) -> pd.DataFrame:
    """The frames of each run's first camera (the one its summary metrics describe), with a replicate column
    (0 for tables written before replicates) and a trajectory id: run, replicate and label."""
    if frames.empty:
        return frames
    first = frames.groupby("run_id", sort=False).camera.transform("first")
    f = frames[frames.camera == first].copy()
    if "replicate" not in f:
        f["replicate"] = 0
    f["trajectory"] = f.run_id.astype(str) + "/" + f.replicate.astype(str) + "/" + f.label.astype(str)
    return f


def units(runs: pd.DataFrame, frames: pd.DataFrame, factors: list[str]) -> pd.DataFrame:
    """One row per unit of observation, a finished run's replicate: its factors, mean composite confidence,
    recall and mean visible fraction. Frames of one replicate are not independent, so they are averaged
    here and only units enter an interval or a test. Runs without a frame table count as one unit."""
    finished = runs[runs.status == "FINISHED"].dropna(subset=["confidence_mean"])
    cols = ["run_id", *factors]
    f = primary(frames)
    parts = []
    if not f.empty:
        f = f.merge(finished[["run_id", "threshold"]], on="run_id")
        f["hit"] = (f.composite >= f.threshold).astype(float)
        per = f.groupby(["run_id", "replicate"], sort=False).agg(
            confidence_mean=("composite", "mean"), recall=("hit", "mean"),
            visible_fraction_mean=("visible_fraction", "mean")).reset_index()
        parts.append(finished[cols].merge(per, on="run_id", sort=False))
    rest = finished[~finished.run_id.isin(f.run_id if not f.empty else [])]
    if len(rest):
        parts.append(rest.reindex(columns=cols + ["confidence_mean", "recall", "visible_fraction_mean"])
                     .assign(replicate=0))
    if not parts:
        return pd.DataFrame(columns=[*cols, "replicate", *RESPONSES, "visible_fraction_mean", "difficulty"])
    obs = pd.concat(parts, ignore_index=True)
    obs["difficulty"] = 1.0 - obs.confidence_mean
    return obs


def main_effects(obs: pd.DataFrame, factors: list[str]) -> pd.DataFrame:
    """Per factor and level (mean over the other factors): units n, mean composite confidence and recall with
    their 95 % bootstrap intervals over units, and the difficulty (1 - confidence) with its interval."""
    parts = []
    for f in factors:
        g = stats.group_cis(obs, [f], RESPONSES)
        g["difficulty"] = 1.0 - g.confidence_mean
        g["difficulty_low"], g["difficulty_high"] = 1.0 - g.confidence_mean_high, 1.0 - g.confidence_mean_low
        g.insert(0, "factor", f.removeprefix("factor."))
        parts.append(g.rename(columns={f: "level"}))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def pair_effects(obs: pd.DataFrame, factors: list[str]) -> pd.DataFrame:
    parts = []
    for a, b in itertools.combinations(factors, 2):
        g = stats.group_cis(obs, [a, b], RESPONSES)
        g.insert(0, "pair", f"{a.removeprefix('factor.')} x {b.removeprefix('factor.')}")
        parts.append(g.rename(columns={a: "level_a", b: "level_b"}))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def significance(obs: pd.DataFrame, factors: list[str]) -> pd.DataFrame:
    """The ANOVA of composite confidence and of recall on the swept factors (replicate as a block). A response
    that cannot be tested has no rows; `attrs["untestable"]` ({response: why}) and `attrs["notes"]` say why, and
    what a test assumed."""
    parts, untestable, notes = [], {}, {}
    for response in RESPONSES:
        table = stats.anova(obs, factors, response, block="replicate")
        if "untestable" in table.attrs:
            untestable[response] = table.attrs["untestable"]
        if "note" in table.attrs:
            notes[response] = table.attrs["note"]
        if not table.empty:
            table.insert(0, "response", response)
            table["units"] = table.attrs["units"]
            parts.append(table)
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()
    out.attrs.update(untestable=untestable, notes=notes)
    return out


def significance_text(anova: pd.DataFrame) -> str:
    """The report's significance section: the table, and each response that was not tested with the reason."""
    why = anova.attrs.get("untestable") or {}
    notes = anova.attrs.get("notes") or {}
    lines = [markdown_table(anova)] if not anova.empty else []
    lines += [f"{r}: not testable: {w}.\n" for r, w in why.items()]
    lines += [f"{r}: {n}.\n" for r, n in notes.items()]
    if not lines:
        lines = ["(not testable: no factor with two levels or more)\n"]
    return "\n".join(lines)


def breakdown(frames: pd.DataFrame, runs: pd.DataFrame, factors: list[str], what: str) -> pd.DataFrame:
    """Mean confidence per label (what="label"), per model ("model") or per target kind ("kind") for every
    combination of the swept factors' levels, with intervals over units: the research's tables (colour x light
    preset, placement x light) come out of a sweep as they are. Long form: what, levels, n, mean, low, high."""
    f = primary(frames)
    if f.empty:
        return pd.DataFrame()
    f = f.merge(runs[["run_id", *factors]], on="run_id")
    if what == "model":
        cols = [c for c in f.columns if c.startswith("conf_")]
        long = f.melt(id_vars=["run_id", "replicate", *factors], value_vars=cols, var_name="what",
                      value_name="confidence")
        long["what"] = long["what"].str.removeprefix("conf_")
    else:
        column = {"label": "label", "kind": "target_kind"}[what]
        if column not in f:
            return pd.DataFrame()
        long = f.rename(columns={column: "what", "composite": "confidence"})
    per = long.groupby(["what", "run_id", "replicate"], sort=False).confidence.mean().reset_index()
    per = per.merge(runs[["run_id", *factors]], on="run_id", sort=False)
    per["levels"] = levels_text(per, factors)
    g = stats.group_cis(per, ["what", "levels"], ["confidence"])
    return g


def by_camera(frames: pd.DataFrame, runs: pd.DataFrame, factors: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Runs with several cameras (issue 11): each camera's mean composite confidence over the frames where it
    sees the target (intervals over units), and in how many trajectories it detected the target first
    (results.per_camera). Both long, for `pivot`; empty for single-camera sweeps."""
    from garage_exp.results.table import per_camera

    if frames.empty or frames.groupby("run_id").camera.nunique().max() < 2:
        return pd.DataFrame(), pd.DataFrame()
    f = frames.merge(runs[["run_id", "threshold", *factors]], on="run_id")
    if "replicate" not in f:
        f["replicate"] = 0
    f["levels"] = levels_text(f, factors)
    seen = f[f.visible_fraction > 0]
    per = seen.groupby(["camera", "levels", "run_id", "replicate"], sort=False).composite.mean().reset_index()
    conf = stats.group_cis(per.rename(columns={"camera": "what", "composite": "confidence"}), ["what", "levels"],
                           ["confidence"])
    firsts = []
    for (run_id, levels), g in f.groupby(["run_id", "levels"], sort=False):
        cams = per_camera(g.drop(columns="levels"), float(g.threshold.iloc[0]))
        firsts += [{"what": c, "levels": levels, "first": n} for c, n in zip(cams.camera, cams["first"])]
    first = pd.DataFrame(firsts).groupby(["what", "levels"], sort=False)["first"].sum().reset_index()
    return conf, first


def levels_text(df: pd.DataFrame, factors: list[str]) -> pd.Series:
    if not factors:
        return pd.Series("all runs", index=df.index)
    return df[factors].astype(str).apply(
        lambda r: ", ".join(f"{f.removeprefix('factor.')}={v}" for f, v in r.items()), axis=1)


def pivot(long: pd.DataFrame, value: str = "confidence") -> pd.DataFrame:
    """A long breakdown as the research's table: rows `what`, columns the levels (sweep order), each cell
    "mean [low, high]"."""
    if long.empty:
        return long
    cell = long.apply(lambda r: with_ci(r[value], r[f"{value}_low"], r[f"{value}_high"]), axis=1)
    table = long.assign(cell=cell).pivot(index="what", columns="levels", values="cell")
    return table[list(dict.fromkeys(long.levels))].loc[list(dict.fromkeys(long.what))].fillna("-")


def number(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:.3f}" if isinstance(v, float) else str(v)


def with_ci(mean, low, high) -> str:
    """"0.612 [0.551, 0.670]"; a mean without an interval (one unit) as "0.612 [-]"; no mean as "-"."""
    if mean is None or math.isnan(mean):
        return "-"
    if low is None or math.isnan(low):
        return f"{mean:.3f} [-]"
    return f"{mean:.3f} [{low:.3f}, {high:.3f}]"


def display(df: pd.DataFrame) -> pd.DataFrame:
    """Columns x, x_low, x_high shown as one "x [low, high]" column."""
    out = pd.DataFrame(index=df.index)
    for col in df.columns:
        if col.endswith(("_low", "_high")) and col.rsplit("_", 1)[0] in df:
            continue
        if f"{col}_low" in df:
            out[col] = [with_ci(m, lo, hi) for m, lo, hi in zip(df[col], df[f"{col}_low"], df[f"{col}_high"])]
        else:
            out[col] = df[col]
    return out


def markdown_table(df: pd.DataFrame) -> str:
    if df.empty:
        return "(none)\n"
    df = display(df)
    cols = list(df.columns)
    lines = ["| " + " | ".join(str(c) for c in cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        lines.append("| " + " | ".join(number(v) for v in r) + " |")
    return "\n".join(lines) + "\n"


def summary(runs: pd.DataFrame, expected: int | None = None, search: bool = False) -> tuple[str, int]:
    """The sweep's summary for the terminal: counts, then one line per failed run. Returns (text, number of
    failed or missing jobs). `expected`: the number of jobs launched, when known (a job without any run,
    e.g. refused for bad input in a worker, counts as failed). `search`: the runs are a study's trials, the
    skipped ones those this command did not run (before a resume, or in another worker: search.sweep)."""
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
    counts = (f"{total} trials' runs: {ran} finished here, {n_skipped} finished before or in another worker" if search
              else f"{total} jobs: {ran} finished, {n_skipped} skipped (finished before)")
    head = (f"garage_exp: sweep summary: {counts}, {len(failed)} failed"
            + (f", {missing} without a run" if missing else ""))
    lines = [head]
    for _, r in failed.iterrows():
        lines.append(f"  {r.status}: {r.run_name} (run {r.run_id}): {r.error or 'no error recorded'}"[:600])
    return "\n".join(lines), len(failed) + missing


def late_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per run whose ego moves: the share of its testable trajectories seen too late to stop, the detection
    distance and time-to-collision at detection, against the critical distance."""
    if "late_testable" not in runs:
        return pd.DataFrame()
    done = runs[runs.late_testable.notna()]
    cols = {"run_name": "run", **late_metrics.LABELS}
    return done.reindex(columns=list(cols)).rename(columns=cols).sort_values("late (share)", ascending=False)
