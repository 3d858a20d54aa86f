"""A job's frame table: one row per frame and camera, and its summary metrics (over all frames, the fairly
visible ones, per camera)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

from garage_exp.results import stats


# (column, the ground-truth record's field, decimals): the target's 3D box height (m), the lamps' direct light at
# its centre and the camera's height (m), from the scene's geometry (perception/groundtruth.py), for the search's
# descriptors (search/descriptors.py)
GEOMETRY = (("target_height", "height", 4), ("target_light", "light", 6), ("camera_height", "camera_height", 4))


def frame_row(shot, camera: str, target, score, model_names: list[str], target_kind: str | None = None,
              replicated: bool = False, off_axis: bool = False) -> dict:
    """One frame's row. target_kind ("vehicle" | "person") is a column only when given: scenes with people give
    it on every row, vehicle-only scenes keep their tables as they were; so is `replicate`, when replicates > 1,
    and `off_axis` (the target's angle from the optical axis, degrees) for rigs with a fisheye camera."""
    row = {
        "shot": shot.index, **({"replicate": shot.replicate} if replicated else {}),
        "label": shot.label, "position": shot.position, "camera": camera,
        "ego_x": round(shot.ego.x, 4), "ego_y": round(shot.ego.y, 4), "ego_yaw": round(shot.ego.yaw, 3),
        "target": shot.target,
        "distance": round(target.distance, 4) if target else math.nan,
        "visible_fraction": round(target.visible_fraction, 6) if target else 0.0,
        "visible_pixels": target.visible_pixels if target else 0,
        "box_height": (target.full_box[3] - target.full_box[1]) if target and target.full_box else 0,
        "truncation": round(target.truncation, 4) if target else math.nan,
        "kitti": target.kitti if target else "out_of_view",
        # what hides most of the target: pillar | vehicle | person | structure | none (perception/groundtruth.py)
        "occluder": target.occluder if target else "out_of_view",
        **{column: round(float(getattr(target, key, math.nan)), digits) if target else math.nan
           for column, key, digits in GEOMETRY},
    }
    if target_kind is not None:
        row["target_kind"] = target_kind
    if off_axis:
        row["off_axis"] = round(target.off_axis, 3) if target else math.nan
    for name, conf in zip(model_names, score.per_model):
        row[f"conf_{name}"] = round(float(conf), 6)
    row["composite"] = round(float(score.composite), 6)
    row["detected"] = bool(score.detected)
    row["false_positives"] = int(score.false_positives)
    return row


def summarise(table: pd.DataFrame, threshold: float, primary: str) -> dict[str, float]:
    """Summary metrics over the primary camera's frames, plus the mean per label (colour, placement)."""
    t = table[table.camera == primary]
    conf = t.composite.to_numpy(dtype=float)
    out = {
        "confidence_mean": float(conf.mean()) if len(conf) else 0.0,
        "confidence_min": float(conf.min()) if len(conf) else 0.0,
        "recall": float((conf >= threshold).mean()) if len(conf) else 0.0,
        "frames_under_threshold": float((conf < threshold).sum()),
        "visible_fraction_mean": float(t.visible_fraction.mean()) if len(t) else 0.0,
        "false_positives": float(t.false_positives.sum()) if len(t) else 0.0,
        "frames": float(len(t)),
    }
    out["difficulty"] = 1.0 - out["confidence_mean"]
    if "replicate" in t and t.replicate.nunique() > 1:  # the interval over replicates, as the report gives it
        per = t.groupby("replicate").composite.mean()
        _, out["confidence_mean_low"], out["confidence_mean_high"] = stats.mean_ci(per)
        out["replicates"] = float(len(per))
    # Breakdowns the sweep report tabulates: per label (a colour, a case-3 placement), per model, per camera.
    for label, group in t.groupby("label", sort=False):
        out[f"label.{_metric_key(label)}"] = float(group.composite.mean())
    for col in [c for c in t.columns if c.startswith("conf_")]:
        out[f"model.{col[5:]}"] = float(t[col].mean())
    for cam, group in table.groupby("camera", sort=False):
        if cam != primary:
            out[f"camera.{_metric_key(cam)}"] = float(group.composite.mean())
    if table.camera.nunique() > 1:  # every camera that sees the target, scored (per_camera)
        for _, row in per_camera(table, threshold).iterrows():
            key = _metric_key(row.camera)
            for col in ("confidence_in_view", "recall_in_view", "first", "in_view"):
                out[f"camera.{key}.{col}"] = float(row[col])
    if "target_kind" in t:  # scenes with people: the mean per kind of target
        for kind, group in t.groupby("target_kind", sort=False):
            out[f"kind.{_metric_key(kind)}"] = float(group.composite.mean())
    return out


@dataclass(frozen=True)
class FairRule:
    """When a frame is a fair test of the detector (the job spec's rule; its values are `search.min_visible`,
    `search.min_box`, `search.max_truncation`, a search or not)."""

    min_visible: float = 0.5
    min_box: float = 25
    max_truncation: float = 0.5

    @classmethod
    def of(cls, node) -> "FairRule":
        """The rule from any node with the three values (the `search` group, a SearchConf)."""
        return cls(float(node.min_visible), float(node.min_box), float(node.max_truncation))


@dataclass(frozen=True)
class JobNames:
    """What a job's headline and plot title name: the levels of case, light, sensor and plan."""

    case: str
    light: str
    sensor: str
    plan: str


def fair_mask(table: pd.DataFrame, search) -> pd.Series:
    """Frames that are a fair test of the detector (a `FairRule`, or any node with its three values): the target at least
    `min_visible` visible, its full box at least `min_box` pixels tall and at most `max_truncation` of it outside
    the image (KITTI's "hard" level allows 25 px and 0.5). A hidden, tiny or cut-off target is not hard, it is
    untestable."""
    return ((table.visible_fraction >= search.min_visible) & (table.box_height >= search.min_box)
            & (table.truncation.fillna(1.0) <= search.max_truncation))


def fair_summary(table: pd.DataFrame, primary: str, search, threshold: float) -> dict[str, float]:
    """The search's objective (garage_exp/search): fair_difficulty = 1 - the mean composite confidence over the
    primary camera's fair frames (fair_mask; NaN when none is)."""
    t = table[table.camera == primary]
    fair = t[fair_mask(t, search)]
    conf = fair.composite.to_numpy(dtype=float)
    mean = float(conf.mean()) if len(conf) else math.nan
    return {"fair_frames": float(len(fair)), "fair_confidence": mean, "fair_difficulty": 1.0 - mean,
            "fair_recall": float((conf >= threshold).mean()) if len(conf) else math.nan}


def per_camera(table: pd.DataFrame, threshold: float) -> pd.DataFrame:
    """Each camera of a rig scored on the frames where it sees the target (visible_fraction > 0): mean composite
    confidence and recall there, the best frame's confidence, and `first`: in how many trajectories (a label and
    replicate) it detected the target first (at the earliest shot; cameras detecting at the same shot share
    it). The camera with the highest confidence_in_view saw it best."""
    t = table.assign(seen=table.visible_fraction > 0, hit=table.composite >= threshold)
    keys = ["label", *(["replicate"] if "replicate" in t else [])]
    firsts: dict[str, int] = {}
    for _, traj in t[t.hit].groupby(keys, sort=False):
        for cam in traj[traj.shot == traj.shot.min()].camera.unique():
            firsts[cam] = firsts.get(cam, 0) + 1
    rows = []
    for cam, g in t.groupby("camera", sort=False):
        seen = g[g.seen]
        first = g[g.hit].shot.min() if g.hit.any() else math.nan
        rows.append({"camera": cam, "frames": len(g), "in_view": int(len(seen)),
                     "confidence_in_view": float(seen.composite.mean()) if len(seen) else 0.0,
                     "recall_in_view": float(seen.hit.mean()) if len(seen) else 0.0,
                     "best_confidence": float(g.composite.max()) if len(g) else 0.0,
                     "first_shot": first, "first": firsts.get(cam, 0)})
    return pd.DataFrame(rows)


def camera_line(cams: pd.DataFrame) -> str:
    """Which camera saw the target first and which best, in one line."""
    if cams.empty or cams.in_view.sum() == 0:
        return "no camera saw the target"
    best = cams.loc[cams.confidence_in_view.idxmax()]
    text = f"best: {best.camera} (mean confidence {best.confidence_in_view:.3f} over {best.in_view} frames in view)"
    if cams["first"].sum() == 0:
        return "never detected; " + text
    first = cams.loc[cams["first"].idxmax()]
    return f"first: {first.camera} (first in {first['first']} trajectories, at shot {first.first_shot:.0f}); " + text


def _metric_key(label: str) -> str:
    """An MLflow-safe name that still reads like the label: "close=large,far=small" -> "close-large/far-small"."""
    text = str(label).replace("=", "-").replace(",", "/")
    return "".join(ch if ch.isalnum() or ch in "_-./" else "_" for ch in text)


def one_line(names: JobNames, summary, cameras: list[str], primary: str) -> str:
    """The job's headline. One rule for every rig: it counts and scores the primary camera's frames (the camera
    the case names in `case.camera`, else the rig's first: the frames the summary metrics cover) and names it;
    cameras.csv and the `cameras:` line score every camera."""
    rig = (f"{primary} camera (the primary of {len(cameras)}; cameras.csv scores each), "
           if len(cameras) > 1 else "")
    return (f"case={names.case} light={names.light} sensor={names.sensor} plan={names.plan}: {rig}"
            f"{int(summary.frames)} frames, confidence mean {summary.confidence_mean:.3f} "
            f"min {summary.confidence_min:.3f}, recall {summary.recall:.2f}, difficulty {summary.difficulty:.3f}")
