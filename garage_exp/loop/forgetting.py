"""Not forgetting (issue 50, item 3): after the last round, does every arm's detector keep D0's recall on what it
was never trained for, the protocol suite (cpnco, cpra, crossing, crouch: each suite and the suites pooled) and the
real photos? A fine-tuning that lowers the failure rate on garage scenarios but forgets a child stepping out, or a
car in a photo, is not a detector an engineer would ship; the goals hold each arm within a tolerance of D0's recall
(`forgetting.protocol_recall`, `forgetting.photo_recall`), or above it.

One row per arm, seed and suite: D0's recall, the arm's, the drop (D0 - arm: positive is forgetting), the tolerance
and whether it holds. The table is descriptive (one seed has no interval); the Holm family of `comparisons.csv`
keeps the seed-paired tests of the same recalls.
"""

from __future__ import annotations

import pandas as pd


def recall_checks(scores: pd.DataFrame, photos: pd.DataFrame, arms: list[str], k: int,
                  protocol_tolerance: float, photo_tolerance: float) -> pd.DataFrame:
    """The recall checks after round k (columns: arm, seed, suite, d0, recall, drop, tolerance, holds)."""
    proto = scores[scores.suite.astype(str).str.startswith("protocol")] if len(scores) else scores
    rows = _against_d0(proto, "suite", "fair_recall", "", arms, k, protocol_tolerance)
    if len(photos):
        rows += _against_d0(photos, "set", "recall", "real:", arms, k, photo_tolerance)
    return pd.DataFrame(rows, columns=["arm", "seed", "suite", "d0", "recall", "drop", "tolerance", "holds"])


def _against_d0(table: pd.DataFrame, by: str, column: str, prefix: str, arms: list[str], k: int,
                tolerance: float) -> list[dict]:
    """Per group of `by` (a suite, a photo set) that D0 was scored on: each arm's round-k `column` against D0's."""
    rows = []
    for suite, group in table.groupby(by, sort=True):
        base = group[group.arm == "D0"]
        if not len(base):
            continue
        d0 = float(base[column].iloc[0])
        if d0 != d0:  # no fair frame in the suite (its frames are every detector's): no recall to keep
            continue
        for arm in arms:
            for _, r in group[(group.arm == arm) & (group["round"] == k)].iterrows():
                rows.append(_row(arm, int(r.seed), f"{prefix}{suite}", d0, float(r[column]), tolerance))
    return rows


def tolerances(cfg) -> tuple[float, float]:
    """The config's (protocol, photo) tolerances; the schema's defaults where a config has none (a report written
    from a config of before this check)."""
    from omegaconf import OmegaConf

    from garage_exp.loop.schema import ForgettingConf

    default = ForgettingConf()
    return (float(OmegaConf.select(cfg, "forgetting.protocol_recall", default=default.protocol_recall)),
            float(OmegaConf.select(cfg, "forgetting.photo_recall", default=default.photo_recall)))


def _row(arm: str, seed: int, suite: str, d0: float, recall: float, tolerance: float) -> dict:
    drop = d0 - recall
    holds = bool(drop <= tolerance + 1e-12) if drop == drop else False  # an arm with no recall has not kept it
    return {"arm": arm, "seed": seed, "suite": suite, "d0": d0, "recall": recall, "drop": drop,
            "tolerance": tolerance, "holds": holds}


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
                    f"{worst.d0:.2f}, allowed drop {worst.tolerance:.2f})")
    head = (f"Not forgetting: {', '.join(kept)} keep{'s' if len(kept) == 1 else ''} D0's recall within the "
            "tolerance on every protocol suite and real-photo set" if kept else "Not forgetting: no arm keeps "
            "D0's recall on every protocol suite and real-photo set")
    return head + ("; " + "; ".join(lost) if lost else "") + "."
