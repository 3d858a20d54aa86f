"""Not forgetting (issue 50, item 3): after the last round, does every arm's detector keep D0's recall on what it
was never trained for, the protocol suite (cpnco, cpra, crossing, crouch: each suite and the suites pooled) and the
real photos? A fine-tuning that lowers the failure rate on garage scenarios but forgets a child stepping out, or a
car in a photo, is not a detector an engineer would ship; the goals hold each arm within a tolerance of D0's recall
(`forgetting.protocol_recall`, `forgetting.photo_recall`), or above it.

One row per arm, seed and suite: D0's recall, the arm's, the drop (D0 - arm: positive is forgetting), the tolerance
and whether it holds. The table is descriptive (one seed has no interval); the Holm family of `comparisons.csv`
keeps the seed-paired tests of the same recalls. Each row also says what the suite can resolve: its objects (a
protocol suite's fair frames, a photo set's targets) and one object's share of the recall (`step`). A suite whose
step is above the tolerance cannot hold a drop of one object (crossing's 4 fair frames: 0.25 against 0.02), and the
report says how many objects a failed check lost, so that an engineer reads "1 of 4" for what it is.
"""

from __future__ import annotations

import pandas as pd


def recall_checks(scores: pd.DataFrame, photos: pd.DataFrame, arms: list[str], k: int,
                  protocol_tolerance: float, photo_tolerance: float) -> pd.DataFrame:
    """The recall checks after round k (columns: arm, seed, suite, d0, recall, drop, tolerance, holds, objects,
    step, lost; objects NaN where the table does not say how many: a report of photos scored before `objects`)."""
    proto = scores[scores.suite.astype(str).str.startswith("protocol")] if len(scores) else scores
    rows = _against_d0(proto, "suite", "fair_recall", "fair_frames", "", arms, k, protocol_tolerance)
    if len(photos):
        rows += _against_d0(photos, "set", "recall", "objects", "real:", arms, k, photo_tolerance)
    return pd.DataFrame(rows, columns=COLUMNS)


COLUMNS = ["arm", "seed", "suite", "d0", "recall", "drop", "tolerance", "holds", "objects", "step", "lost"]


def _against_d0(table: pd.DataFrame, by: str, column: str, count: str, prefix: str, arms: list[str], k: int,
                tolerance: float) -> list[dict]:
    """Per group of `by` (a suite, a photo set) that D0 was scored on: each arm's round-k `column` against D0's;
    `count`: the column holding how many objects the recall is over (the same for every detector of a group)."""
    rows = []
    for suite, group in table.groupby(by, sort=True):
        base = group[group.arm == "D0"]
        if not len(base):
            continue
        d0 = float(base[column].iloc[0])
        if d0 != d0:  # no fair frame in the suite (its frames are every detector's): no recall to keep
            continue
        objects = float(base[count].iloc[0]) if count in base else float("nan")
        for arm in arms:
            for _, r in group[(group.arm == arm) & (group["round"] == k)].iterrows():
                rows.append(_row(arm, int(r.seed), f"{prefix}{suite}", d0, float(r[column]), tolerance, objects))
    return rows


def tolerances(cfg) -> tuple[float, float]:
    """The config's (protocol, photo) tolerances; the schema's defaults where a config has none (a report written
    from a config of before this check)."""
    from omegaconf import OmegaConf

    from garage_exp.loop.schema import ForgettingConf

    default = ForgettingConf()
    return (float(OmegaConf.select(cfg, "forgetting.protocol_recall", default=default.protocol_recall)),
            float(OmegaConf.select(cfg, "forgetting.photo_recall", default=default.photo_recall)))


def _row(arm: str, seed: int, suite: str, d0: float, recall: float, tolerance: float, objects: float) -> dict:
    drop = d0 - recall
    holds = bool(drop <= tolerance + 1e-12) if drop == drop else False  # an arm with no recall has not kept it
    known = objects == objects and objects > 0
    # objects lost net (D0's hits minus the arm's): a recall over n objects moves in steps of 1/n
    lost = round(drop * objects) if known and drop == drop else None
    return {"arm": arm, "seed": seed, "suite": suite, "d0": d0, "recall": recall, "drop": drop,
            "tolerance": tolerance, "holds": holds, "objects": int(objects) if known else None,
            "step": 1.0 / objects if known else None, "lost": lost}


def _lost(row) -> str:
    """', 1 of 4 objects' for a failed check whose suite says its size; '' where it does not."""
    if row.objects is None or row.objects != row.objects or row.lost is None or row.lost != row.lost:
        return ""
    coarse = "; one object is more than the tolerance" if row.step > row.tolerance + 1e-12 else ""
    return f", {int(row.lost)} of {int(row.objects)} objects{coarse}"


def sentence(checks: pd.DataFrame) -> str:
    """One sentence for report.md: which arms keep D0's recall everywhere, and where the others forget."""
    if not len(checks):
        return "Not forgetting: no protocol suite or real-photo set was scored against D0."
    kept, lost = [], []
    for arm, group in checks.groupby("arm", sort=False):
        bad = group[~group.holds]
        if not len(bad):
            kept.append(arm)
            continue
        worst = bad.sort_values("drop", ascending=False).iloc[0]
        lost.append(f"{arm} forgets on {len(bad)} of {len(group)} (worst {worst.suite}: {worst.recall:.2f} vs D0 "
                    f"{worst.d0:.2f}, allowed drop {worst.tolerance:.2f}{_lost(worst)})")
    head = (f"Not forgetting: {', '.join(kept)} keep{'s' if len(kept) == 1 else ''} D0's recall within the "
            "tolerance on every protocol suite and real-photo set" if kept else "Not forgetting: no arm keeps "
            "D0's recall on every protocol suite and real-photo set")
    return head + ("; " + "; ".join(lost) if lost else "") + "."
