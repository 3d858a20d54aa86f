"""Detection against visibility, in the literature's terms: recall and mean confidence per model and for the
composite by CityPersons' visible-fraction bins and by KITTI level, with intervals over trajectories, and the
visible fraction at which recall crosses 0.5 from a logistic fit."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pandas as pd

from garage_exp.core.state import STATE
from garage_exp.results import stats
from garage_exp.tracking import runs as tracking
from garage_exp.report.tables import primary

COMPOSITE = "composite"


def frame_tables(mlc, runs: pd.DataFrame) -> pd.DataFrame:
    """Every finished run's frame table (its `frames.csv` artifact) with its run id; runs without one (dry runs)
    are left out."""
    return run_tables(mlc, runs, "frames.csv")


def run_tables(mlc, runs: pd.DataFrame, artifact: str) -> pd.DataFrame:
    """Every finished run's CSV artifact `artifact`, concatenated with its run id; runs without one, or with an
    empty one, are left out."""
    # One progress bar per downloaded table would bury the sweep's summary.
    STATE.setenv("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false", "command", default=True)
    parts = []
    with tempfile.TemporaryDirectory(prefix="garage_tables_") as tmp:
        for run_id in runs[runs.status == "FINISHED"].run_id:
            names = {a.path for a in tracking.retry(lambda r=run_id: mlc.list_artifacts(r))}
            if artifact not in names:
                continue
            dst = Path(tmp) / run_id
            dst.mkdir()
            path = tracking.retry(lambda r=run_id, d=dst: mlc.download_artifacts(r, artifact, str(d)))
            try:
                table = pd.read_csv(path)
            except pd.errors.EmptyDataError:
                continue
            if not table.empty:
                parts.append(table.assign(run_id=run_id))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def scores(frames: pd.DataFrame) -> list[str]:
    """The frame table's score columns: one per model, then the composite."""
    return [c for c in frames.columns if c.startswith("conf_")] + [COMPOSITE]


def in_view(frames: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """The primary camera's frames with the target in view, with each run's detection threshold."""
    f = primary(frames)
    if f.empty:
        return f
    f = f.merge(runs[["run_id", "threshold"]], on="run_id")
    return f[f.kitti != "out_of_view"] if "kitti" in f else f


def by_bins(frames: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """Per score (model or composite) and bin (visible fraction, KITTI level): frames, trajectories, recall and
    mean confidence with cluster-bootstrap intervals over trajectories."""
    f = in_view(frames, runs)
    if f.empty:
        return pd.DataFrame()
    f = f.assign(visibility=stats.visibility_bin(f.visible_fraction).to_numpy())
    rows = []
    for score in scores(f):
        hit = (f[score] >= f.threshold).astype(float)
        for kind, column, order in (("visible fraction", "visibility", [b[0] for b in stats.VISIBILITY_BINS]),
                                    ("KITTI level", "kitti", list(stats.KITTI_ORDER))):
            for level in order:
                mask = (f[column] == level).to_numpy()
                row = {"model": score.removeprefix("conf_"), "by": kind, "bin": level, "frames": int(mask.sum())}
                rec = stats.ratio_ci(hit[mask], f.trajectory[mask])
                conf = stats.ratio_ci(f[score][mask], f.trajectory[mask])
                row.update(trajectories=rec[3], recall=rec[0], recall_low=rec[1], recall_high=rec[2],
                           confidence=conf[0], confidence_low=conf[1], confidence_high=conf[2])
                rows.append(row)
    return pd.DataFrame(rows)


def curves(frames: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """Per score: the visible fraction at which recall crosses 0.5 (logistic fit), its interval and slope."""
    f = in_view(frames, runs)
    if f.empty:
        return pd.DataFrame()
    rows = []
    for score in scores(f):
        fit = stats.recall_curve(f.assign(score_hit=(f[score] >= f.threshold).astype(float)), "score_hit", 0.5)
        rows.append({"model": score.removeprefix("conf_"), "frames": int(fit["frames"]), "v50": fit["v50"],
                     "v50_low": fit["v50_low"], "v50_high": fit["v50_high"], "slope": fit["slope"],
                     "reading": reading(fit["v50"]), "fit": fit.get("fit")})
    return pd.DataFrame(rows)


def reading(v50: float) -> str:
    """What a crossing outside 0..1 means: the fit extrapolates past what a visible fraction can be."""
    if v50 != v50:
        return "no fit (one outcome, or too little spread of visibility)"
    if v50 > 1:
        return "recall stays below 0.5 even fully visible"
    if v50 < 0:
        return "recall is above 0.5 even fully hidden"
    return ""


def miss_rate_ratio(bins: pd.DataFrame, model: str = "composite") -> float:
    """Miss rate (1 - recall) in CityPersons' "heavy" bin over that in "reasonable": the literature's headline
    (CityPersons: 3-4x for the detectors of its time)."""
    b = bins[(bins.model == model) & (bins.by == "visible fraction")].set_index("bin")
    names = [n for n, _, _ in stats.VISIBILITY_BINS]
    try:
        reasonable, heavy = 1 - b.loc[names[0], "recall"], 1 - b.loc[names[1], "recall"]
    except KeyError:
        return float("nan")
    return float(heavy / reasonable) if reasonable > 0 else float("nan")
