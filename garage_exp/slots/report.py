"""The sweep report's slot section (issue 25): how well slots were found on the bird's-eye view, per factor level,
with 95 % intervals over units, and which factor makes slot finding hardest.

A run of a slot case logs `slots.csv` (garage_exp/slots/frames.py): one row per BEV frame with the slot detector's
counts (slots/results.score: point_tp, point_fp, point_fn, slot_tp, slot_fp, slot_fn, occupancy_right,
occupancy_n; fair truth slots only). A unit is a run's replicate, as for the object metrics: its frames' counts
are pooled into rates (PS2.0's recall and precision over all its frames), and intervals are bootstrapped over
units, never frames.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import pandas as pd

from garage_exp.results import stats
from garage_exp.tracking import runs as tracking

# response -> (numerator count, the other count of its denominator)
RATES = {"slot_recall": ("slot_tp", "slot_fn"), "slot_precision": ("slot_tp", "slot_fp"),
         "slot_point_recall": ("point_tp", "point_fn"), "slot_point_precision": ("point_tp", "point_fp"),
         "slot_occupancy_acc": ("occupancy_right", None)}
RESPONSES = list(RATES)


def _rate(num: float, den: float) -> float:
    return num / den if den else math.nan


def slot_units(runs: pd.DataFrame, frames: pd.DataFrame, factors: list[str]) -> pd.DataFrame:
    """One row per run's replicate: its factors and pooled slot rates; empty when no frame was scored."""
    if frames.empty or "slot_tp" not in frames:
        return pd.DataFrame()
    f = frames.copy()
    if "replicate" not in f:
        f["replicate"] = 0
    counts = [c for c in ("point_tp", "point_fp", "point_fn", "slot_tp", "slot_fp", "slot_fn", "occupancy_right",
                          "occupancy_n") if c in f]
    per = f.groupby(["run_id", "replicate"], sort=False)[counts].sum().reset_index()
    for name, (num, other) in RATES.items():
        if num not in per:
            per[name] = math.nan
            continue
        den = per["occupancy_n"] if other is None else per[num] + per[other]
        per[name] = [_rate(n, d) for n, d in zip(per[num], den)]
    per["fair_slots"] = per.get("slot_tp", 0) + per.get("slot_fn", 0)
    return runs[["run_id", *factors]].merge(per, on="run_id", sort=False)


def slot_effects(obs: pd.DataFrame, factors: list[str]) -> pd.DataFrame:
    """Per factor and level: units n and each slot rate's mean with its 95 % interval over units."""
    parts = []
    for f in factors:
        g = stats.group_cis(obs, [f], RESPONSES)
        g.insert(0, "factor", f.removeprefix("factor."))
        parts.append(g.rename(columns={f: "level"}))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def hardest(effects: pd.DataFrame, response: str = "slot_recall") -> tuple[str, str, float] | None:
    """The factor whose levels spread `response` most, its worst level and the spread (best minus worst mean);
    None when no factor spreads it."""
    if effects.empty or effects[response].isna().all():
        return None
    best = None
    for factor, g in effects.dropna(subset=[response]).groupby("factor", sort=False):
        spread = float(g[response].max() - g[response].min())
        if spread > 0 and (best is None or spread > best[2]):
            best = (str(factor), str(g.loc[g[response].idxmin(), "level"]), spread)
    return best  # None too when no factor's levels differ


def section(effects: pd.DataFrame, markdown_table, with_ci) -> list[str]:
    """The report's slot section (markdown lines); none when no run scored slots. The sweep report hands over its
    table and interval formats (report/tables.py's markdown_table and with_ci: the report sits above slots)."""
    if effects.empty:
        return []
    cells = effects.copy()
    for r in RESPONSES:
        cells[r] = [with_ci(m, lo, hi) for m, lo, hi in zip(cells[r], cells[f"{r}_low"], cells[f"{r}_high"])]
    table = cells[["factor", "level", "n", *RESPONSES]]
    text = ["## Slot finding on the bird's-eye view (fair slots; PS2.0 metrics; docs/slots.md)\n",
            "Per factor level, mean over the other factors; each unit is a run's replicate (its frames' counts "
            "pooled), 95 % bootstrap intervals over units.\n", markdown_table(table)]
    worst = hardest(effects)
    if worst is not None:
        text.append(f"Hardest factor for slot recall: **{worst[0]}** (recall spread {worst[2]:.3f} across its "
                    f"levels; lowest at {worst[0]}={worst[1]}).\n")
    return text


def pictures(mlc, units: pd.DataFrame, effects: pd.DataFrame, out: Path) -> list[str]:
    """The hardest factor in frames: a BEV frame (truth green/red, detections blue) of its easiest unit at its
    best level and of its hardest unit at its worst level, copied into the report; markdown lines."""
    worst = hardest(effects)
    if worst is None or units.empty:
        return []
    factor, low_level, _ = worst
    column = next((c for c in units.columns if c.removeprefix("factor.") == factor), None)
    rates = effects[effects.factor == factor].dropna(subset=["slot_recall"])
    if column is None or rates.empty:
        return []
    high_level = str(rates.loc[rates.slot_recall.idxmax(), "level"])
    lines = []
    for level, pick in ((high_level, "idxmax"), (low_level, "idxmin")):
        at = units[units[column].astype(str) == level].dropna(subset=["slot_recall"])
        if at.empty:
            continue
        unit = at.loc[getattr(at.slot_recall, pick)()]
        names = sorted(a.path for a in tracking.retry(lambda r=unit.run_id: mlc.list_artifacts(r, "frames"))
                       if a.path.endswith("_bev.png"))
        if not names:
            continue
        with tempfile.TemporaryDirectory(prefix="garage_slots_") as tmp:
            path = tracking.retry(lambda r=unit.run_id, n=names[len(names) // 2]: mlc.download_artifacts(r, n, tmp))
            name = f"slots_{factor}_{level}.png".replace("/", "_").replace(" ", "_")
            (out / name).write_bytes(Path(path).read_bytes())
        lines.append(f"![{factor}={level}: slot recall {unit.slot_recall:.2f}]({name})\n\n"
                     f"*{factor}={level}, run {unit.run_id[:8]} (slot recall {unit.slot_recall:.2f}): its middle "
                     "BEV frame; truth slots green (free) and red (occupied), detections blue.*\n")
    return ["## Slot finding: the hardest factor in frames\n", *lines] if lines else []
