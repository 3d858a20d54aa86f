"""What a job leaves behind: the frame table, summary metrics, the confidence plot, annotated frames and the
optional YOLO-format dataset."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from garage_exp import stats

COCO_IDS = {"person": 0, "car": 2, "bus": 5, "truck": 7}
PERSON_CLASSES = ("person",)
KIND_TO_COCO = {"car": "car", "suv": "car", "pickup": "truck", "van": "truck", "bus": "bus", "truck": "truck"}


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


def fair_mask(table: pd.DataFrame, search) -> pd.Series:
    """Frames that are a fair test of the detector (the search's rule, `search.*`): the target at least
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


def one_line(cfg, summary: dict, frames: int) -> str:
    return (f"case={cfg.case.name} light={cfg.light.name} sensor={cfg.sensor.name} plan={cfg.plan.name}: "
            f"{frames} frames, confidence mean {summary['confidence_mean']:.3f} min {summary['confidence_min']:.3f}, "
            f"recall {summary['recall']:.2f}, difficulty {summary['difficulty']:.3f}")


def plot_confidence(table: pd.DataFrame, path: Path, xlabel: str, cfg) -> Path:
    """Composite confidence against position per label, visible fraction on a second axis (as the
    research's figures)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    primary = table.camera.iloc[0] if len(table) else ""
    t = table[table.camera == primary]
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    ax2 = ax.twinx()
    labels = list(dict.fromkeys(t.label))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    single_frame = all(len(g) == 1 for _, g in t.groupby("label"))
    for k, label in enumerate(labels):
        g = t[t.label == label]
        c = colours[k % len(colours)]
        style = "o" if single_frame else "-o"
        ax.plot(g.position, g.composite, style, color=c, ms=3, label=f"confidence {label}")
        ax2.plot(g.position, g.visible_fraction, "--", color=c, alpha=0.5, lw=1)
    ax.axhline(cfg.detector.threshold, color="grey", lw=0.8, ls=":")
    ax.set_ylim(-0.02, 1.02)
    ax2.set_ylim(-0.02, 1.02)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("composite confidence (mean over models)")
    ax2.set_ylabel("visible fraction (dashed)")
    ax.set_title(f"case {cfg.case.name}, light {cfg.light.name}, sensor {cfg.sensor.name}, plan {cfg.plan.name}")
    if len(labels) <= 14:
        ax.legend(loc="lower left", fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def draw_boxes(rgb: np.ndarray, target, dets, score=None, min_conf: float = 0.25,
               classes=("car", "truck", "bus")) -> np.ndarray:
    """Ground truth in green (full box) and yellow (visible part); vehicle detections (and person detections
    when the target is a person) at or above min_conf in red with their model's confidence."""
    import cv2

    img = np.ascontiguousarray(rgb).copy()
    if getattr(target, "kind", "vehicle") == "person":
        classes = (*classes, *PERSON_CLASSES)
    if target is not None and target.full_box:
        x1, y1, x2, y2 = map(int, target.full_box)
        cv2.rectangle(img, (x1, y1), (x2, y2), (0, 220, 0), 2)
        if target.visible_box:
            x1, y1, x2, y2 = map(int, target.visible_box)
            cv2.rectangle(img, (x1, y1), (x2, y2), (240, 220, 0), 1)
    for model in dets:
        for box, conf, cls in zip(model.boxes, model.confs, model.classes):
            if conf < min_conf or cls not in classes:
                continue
            x1, y1, x2, y2 = map(int, box)
            cv2.rectangle(img, (x1, y1), (x2, y2), (230, 40, 40), 1)
            cv2.putText(img, f"{cls} {conf:.2f}", (x1, max(10, y1 - 3)), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                        (230, 40, 40), 1, cv2.LINE_AA)
    if score is not None:
        cv2.putText(img, f"composite {score.composite:.2f}", (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (255, 255, 255), 1, cv2.LINE_AA)
    return img


def save_frame(path: Path, rgb, target, dets, score=None, compress_level: int = 6) -> Path:
    from PIL import Image

    Image.fromarray(draw_boxes(rgb, target, dets, score)).save(path, compress_level=compress_level)
    return path


def key_indices(rows: list[dict]) -> set[int]:
    """Rows worth keeping pictures of: the first, the hardest (lowest composite) and the last."""
    if not rows:
        return set()
    hardest = min(range(len(rows)), key=lambda k: (rows[k]["composite"], k))
    return {rows[0]["shot"], rows[hardest]["shot"], rows[-1]["shot"]}


def prune_key_frames(keep: dict, rows: list[dict]) -> dict:
    wanted = key_indices(rows)
    return {k: v for k, v in keep.items() if k[0] in wanted}


def save_key_frames(keep: dict, table: pd.DataFrame, frames_dir: Path) -> list[Path]:
    rows = table.to_dict("records")
    if not rows:
        return []
    hardest = min(range(len(rows)), key=lambda k: (rows[k]["composite"], k))
    # One picture per role, even when the hardest frame is also the first or the last.
    roles = (("first", rows[0]["shot"]), ("hardest", rows[hardest]["shot"]), ("last", rows[-1]["shot"]))
    paths = []
    for role, wanted in roles:
        for (shot, cam), (rgb, target, dets) in sorted(keep.items()):
            if shot == wanted:
                paths.append(save_frame(frames_dir / f"{role}_{shot:04d}_{cam}.png", rgb, target, dets))
    return paths


def save_hardest_fair(keep: dict, table: pd.DataFrame, frames_dir: Path, primary: str, search) -> Path | None:
    """A search trial's picture: the primary camera's hardest fair frame (lowest composite; fair_mask), the frame
    its difficulty (fair_summary) counts, boxes drawn."""
    t = table[table.camera == primary]
    fair = t[fair_mask(t, search)]
    if fair.empty:
        return None
    row = fair.loc[fair.composite.idxmin()]
    item = keep.get((int(row["shot"]), row["camera"]))
    if item is None:
        return None
    rgb, target, dets = item
    # PNG level 1: 0.036 s against 0.062 s (level 6) for a rendered frame here, 1.6x the bytes
    return save_frame(frames_dir / f"hardest_fair_{int(row['shot']):04d}_{row['camera']}.png", rgb, target, dets,
                      compress_level=1)


class DatasetWriter:
    """Frames with YOLO-format labels from ground truth (class x_centre y_centre w h, normalised; COCO ids:
    person 0, car 2, bus 5, truck 7), so a detector can be fine-tuned on the hard cases."""

    def __init__(self, root: Path):
        self.root = root
        (root / "images").mkdir(parents=True, exist_ok=True)
        (root / "labels").mkdir(parents=True, exist_ok=True)

    def add(self, stem: str, rgb: np.ndarray, truth, scene) -> None:
        from PIL import Image

        h, w = rgb.shape[:2]
        Image.fromarray(rgb).save(self.root / "images" / f"{stem}.png")
        lines = []
        for t in labelled(truth):
            x1, y1, x2, y2 = t.full_box
            lines.append(f"{COCO_IDS[coco_class(scene, t)]} {(x1 + x2) / 2 / w:.6f} {(y1 + y2) / 2 / h:.6f} "
                         f"{(x2 - x1) / w:.6f} {(y2 - y1) / h:.6f}")
        (self.root / "labels" / f"{stem}.txt").write_text("\n".join(lines) + ("\n" if lines else ""))

    def finish(self) -> Path:
        import yaml

        # All 80 COCO names with COCO's ids, so a COCO-pretrained detector fine-tunes on it without remapping.
        data = {"path": str(self.root), "train": "images", "val": "images", "names": coco_names()}
        (self.root / "data.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
        return self.root


def coco_names() -> dict[int, str]:
    """COCO's 80 class names by id, from ultralytics' own dataset config (no download)."""
    from importlib.resources import files

    import yaml

    text = (files("ultralytics") / "cfg" / "datasets" / "coco.yaml").read_text()
    return {int(k): str(v) for k, v in yaml.safe_load(text)["names"].items()}


def labelled(truth) -> list:
    """The actors a dataset labels (in every format): those with at least one visible pixel."""
    return [t for t in truth if t.visible_box and t.visible_pixels > 0]


def coco_class(scene, t) -> str:
    """The COCO class name of a ground-truth record: person, or its vehicle kind's (car, bus, truck)."""
    if getattr(t, "kind", "vehicle") == "person":
        return "person"
    return KIND_TO_COCO.get(vehicle_kind(scene, t.name), "car")


def vehicle_kind(scene, name: str) -> str:
    """car, suv, pickup, van, bus or truck, from the entity's model name ('car' when the scene lacks it)."""
    try:
        entity = scene.entity(name)
    except KeyError:
        return "car"
    from garage_exp.scene.kinds import kind_of

    return kind_of(entity.model or "")
