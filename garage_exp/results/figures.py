"""A job's pictures: the confidence plot along the trajectory and frames with their boxes drawn (the first,
hardest and last, or a search trial's hardest fair frame)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from garage_exp.results.labels import PERSON_CLASSES
from garage_exp.results.table import JobNames, fair_mask


def title(names: JobNames) -> str:
    """The confidence plot's title: the job's levels."""
    return f"case {names.case}, light {names.light}, sensor {names.sensor}, plan {names.plan}"


def plot_confidence(table: pd.DataFrame, path: Path, xlabel: str, threshold: float, heading: str) -> Path:
    """Composite confidence against position per label, visible fraction on a second axis (as the
    research's figures); a dotted line at the detection `threshold`, `heading` on top (`title`)."""
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
    ax.axhline(threshold, color="grey", lw=0.8, ls=":")
    ax.set_ylim(-0.02, 1.02)
    ax2.set_ylim(-0.02, 1.02)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("composite confidence (mean over models)")
    ax2.set_ylabel("visible fraction (dashed)")
    ax.set_title(heading)
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
        for box, conf, cls in zip(model.boxes, model.scores, model.classes):
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


def save_frame(path: Path, rgb, target, dets, score=None, quick: bool = False) -> Path:
    """The frame with its boxes drawn, as PNG. quick: for a search trial's one picture, written by OpenCV with zlib's
    run-length strategy at level 1: 3.8 ms a 320 x 240 frame and 115 kB, against 6.5 ms and 135 kB from Pillow at
    level 1 and 22 ms and 118 kB at its default level 6 (20 rendered garage frames, measured on an Intel Xeon). The
    pixels are the same: PNG is lossless."""
    picture = draw_boxes(rgb, target, dets, score)
    if quick:
        import cv2

        ok, data = cv2.imencode(".png", np.ascontiguousarray(picture[..., ::-1]),
                                [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE])
        if not ok:
            raise OSError(f"OpenCV could not encode {path.name} as PNG")
        Path(path).write_bytes(data.tobytes())
        return path
    from PIL import Image

    Image.fromarray(picture).save(path, compress_level=6)
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
    return save_frame(frames_dir / f"hardest_fair_{int(row['shot']):04d}_{row['camera']}.png", rgb, target, dets,
                      quick=True)
