"""Scoring a detector on held-out scenarios: the frames a study rendered (each trial's dataset), run through the
project's own Detector and score_target, as a job scores them, without rendering them again.

Per frame: the target's confidence (0 when missed) and whether it is a fair test (the search's rule). Per
detector and suite: fair recall, fair difficulty, recall by the target's visible fraction, and mAP50 over every
labelled actor by COCOeval on the exported COCO file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from garage_exp.core.plain import settings
from garage_exp.search.schema import SearchConf
from garage_exp.exports.coco import CATEGORY_IDS
from garage_exp.loop.steps import Trial
from garage_exp.perception.detect import GTBox, score_target
from garage_exp.results import cocoeval
from garage_exp.results.table import fair_mask

VISIBLE_BINS = (0.0, 0.25, 0.5, 0.75, 1.0001)


def xyxy(bbox) -> tuple[float, float, float, float]:
    x, y, w, h = bbox
    return (x, y, x + w, y + h)


def score_frames(model: Path, imgsz: int, trials: list[Trial], threshold: float, keep_coco: list | None = None
                 ) -> pd.DataFrame:
    """One row per frame of the trials' primary camera: trial, shot, image, visible fraction, box height,
    truncation, fair, confidence, detected. Every detection of a COCO class the datasets label goes to
    `keep_coco` as (trial, file name, category id, xywh, score), for mAP."""
    from omegaconf import OmegaConf
    from PIL import Image

    from garage_exp.perception.schema import DetectorConf
    from garage_exp.perception.detect import build_detector

    # The project's one factory, with the defaults a job uses (classes, conf 0.05), this model alone.
    detector = build_detector(settings(OmegaConf.structured(DetectorConf)), models=[str(model)], imgsz=imgsz,
                              registry=None)
    detector.check()
    rows = []
    for trial in trials:
        table = pd.read_csv(trial.output_dir / "frames.csv")
        table = table[table.camera == table.camera.iloc[0]]
        coco = json.loads((trial.dataset / "coco.json").read_text())
        by_image = {im["id"]: im["file_name"] for im in coco["images"]}
        targets = {(by_image[a["image_id"]], a["attributes"]["name"]): a for a in coco["annotations"]}
        for row in table.itertuples():
            name = f"{int(row.shot):04d}_{row.camera}.png"
            rgb = np.asarray(Image.open(trial.dataset / "images" / name).convert("RGB"))
            dets = detector.detect([rgb])[0]  # a dataset image: no camera at hand
            ann = targets.get((name, row.target))
            truth = None if ann is None else GTBox(xyxy(ann["bbox"]), xyxy(ann["attributes"]["visible_bbox"]),
                                                   "person" if ann["category_id"] == CATEGORY_IDS["person"]
                                                   else "vehicle")
            score = score_target(dets, truth, iou_threshold=0.5, match="full", threshold=threshold,
                                 **detector.scoring())
            rows.append({"study": trial.study, "trial": trial.number, "shot": int(row.shot),
                         "image": str(trial.dataset / "images" / name), "visible_fraction": row.visible_fraction,
                         "box_height": row.box_height, "truncation": row.truncation, "confidence": score.composite,
                         "detected": score.detected})
            if keep_coco is not None:
                for box, conf, cls in zip(dets[0].boxes, dets[0].scores, dets[0].classes):
                    if cls in CATEGORY_IDS:
                        x1, y1, x2, y2 = (float(v) for v in box)
                        keep_coco.append((trial.number, name, CATEGORY_IDS[cls], [x1, y1, x2 - x1, y2 - y1],
                                          float(conf)))
    frames = pd.DataFrame(rows)
    frames["fair"] = fair_mask(frames, SearchConf()).to_numpy() if len(frames) else []
    return frames


def map50(trials: list[Trial], detections: list) -> float:
    """COCO AP at IoU 0.5 over every labelled actor of the trials' datasets (their COCO files merged)."""
    gt = {"images": [], "annotations": [], "categories": []}
    ids = {}
    for trial in trials:
        coco = json.loads((trial.dataset / "coco.json").read_text())
        gt["categories"] = gt["categories"] or coco["categories"]
        remap = {}
        for im in coco["images"]:
            ids[(trial.number, im["file_name"])] = remap[im["id"]] = len(gt["images"]) + 1
            gt["images"].append({**im, "id": remap[im["id"]]})
        for a in coco["annotations"]:
            gt["annotations"].append({**a, "id": len(gt["annotations"]) + 1, "image_id": remap[a["image_id"]]})
    dts = [{"image_id": ids[(t, name)], "category_id": c, "bbox": b, "score": s} for t, name, c, b, s in detections
           if (t, name) in ids]
    return cocoeval.ap50(gt, dts)


def summarise(frames: pd.DataFrame, ap50: float) -> dict:
    fair = frames[frames.fair]
    out = {"frames": len(frames), "fair_frames": len(fair),
           "fair_recall": float(fair.detected.mean()) if len(fair) else float("nan"),
           "fair_difficulty": float(1.0 - fair.confidence.mean()) if len(fair) else float("nan"), "map50": ap50}
    seen = frames[(frames.visible_fraction > 0) & (frames.box_height >= SearchConf().min_box)]
    for lo, hi in zip(VISIBLE_BINS[:-1], VISIBLE_BINS[1:]):
        part = seen[(seen.visible_fraction >= lo) & (seen.visible_fraction < hi)]
        out[f"recall_vis_{lo:.2f}-{min(hi, 1.0):.2f}"] = float(part.detected.mean()) if len(part) else float("nan")
    return out


def evaluate(model: Path, imgsz: int, trials: list[Trial], threshold: float) -> tuple[dict, pd.DataFrame]:
    detections: list = []
    frames = score_frames(model, imgsz, trials, threshold, detections)
    return summarise(frames, map50(trials, detections)), frames


def scored(eval_dir: Path, name: str, suite: str, weights: str, imgsz: int, trials: list[Trial], threshold: float
           ) -> tuple[pd.DataFrame, list]:
    """A detector's frames of a suite and its detections, scored once and kept under eval_dir/name/ (a rerun of the
    loop reads them back; other weights under the same name are scored again)."""
    import hashlib

    folder = eval_dir / name
    digest = hashlib.sha256(Path(weights).read_bytes()).hexdigest()[:16]
    meta = folder / f"{suite}.json"
    if meta.is_file():
        kept = json.loads(meta.read_text())
        if kept["weights"] == digest and kept["trials"] == [f"{t.study}#{t.number}" for t in trials]:
            frames = pd.read_csv(folder / f"{suite}.csv") if kept["frames"] else pd.DataFrame()
            return frames, [tuple(d) for d in kept["detections"]]
    detections: list = []
    frames = score_frames(Path(weights), imgsz, trials, threshold, detections)
    folder.mkdir(parents=True, exist_ok=True)
    frames.to_csv(folder / f"{suite}.csv", index=False)
    meta.write_text(json.dumps({"weights": digest, "trials": [f"{t.study}#{t.number}" for t in trials],
                                "frames": len(frames), "detections": detections}))
    return frames, detections


def easy_suite(eval_dir: Path, held: list[Trial], d0: dict, cfg) -> list[Trial]:
    """The easy held-out suite: the easiest third of the failure-rate sample's fairly visible scenarios, by D0's
    own fair difficulty on them."""
    done = [t for t in held if t.state == "COMPLETE" and t.dataset is not None]
    frames, _ = scored(eval_dir, "D0", "heldout", d0["weights"], int(cfg.imgsz), done, float(cfg.threshold))
    fair = frames[frames.fair].groupby("trial").confidence.mean() if len(frames) else pd.Series(dtype=float)
    ranked = sorted((t for t in done if t.number in fair.index), key=lambda t: (float(fair[t.number]), -t.number),
                    reverse=True)
    return ranked[:max(1, len(ranked) // 3)]


def score_all(eval_dir: Path, cfg, detectors: dict, held: list[Trial], easy: list[Trial],
              protocol: dict[str, list[Trial]], last: dict, parts: dict[str, list[Trial]] | None = None
              ) -> pd.DataFrame:
    """One row per detector and suite: the failure rate on the held-out sample (every detector; and on each of
    its `parts`, suite `heldout:<part>`, from the same scored frames), fair recall and mAP50 on the easy suite and
    the protocol suite (D0 and the last round's detectors)."""
    from garage_exp.loop import heldout

    done = [t for t in held if t.state == "COMPLETE" and t.dataset is not None]
    easy_ids = {t.number for t in easy}
    rows = []
    for name, d in detectors.items():
        who = {"detector": name, "arm": d["arm"], "round": d["round"], "seed": d["seed"]}
        frames, dets = scored(eval_dir, name, "heldout", d["weights"], int(cfg.imgsz), done, float(cfg.threshold))
        rows.append({**who, "suite": "heldout", **heldout.failures(frames, held, float(cfg.hard_below)),
                     "fair_recall": float(frames[frames.fair].detected.mean()) if len(frames) else float("nan")})
        for part, trials in (parts or {}).items():  # the same frames, counted over the part's scenarios alone
            rows.append({**who, "suite": f"heldout:{part}", **heldout.failures(frames, trials, float(cfg.hard_below))})
        if name not in last:
            continue
        part = frames[frames.trial.isin(easy_ids)]
        rows.append({**who, "suite": "easy", **summarise(part, map50(easy, [x for x in dets if x[0] in easy_ids]))})
        pooled, pooled_trials, pooled_dets = [], [], []
        for label, trials in protocol.items():
            f, p = scored(eval_dir, name, f"protocol_{label}", d["weights"], int(cfg.imgsz), trials,
                          float(cfg.threshold))
            rows.append({**who, "suite": f"protocol:{label}", **summarise(f, map50(trials, p))})
            pooled.append(f)
        if pooled:
            everything = pd.concat(pooled, ignore_index=True)
            fair = everything[everything.fair]
            rows.append({**who, "suite": "protocol", "frames": len(everything), "fair_frames": len(fair),
                         "fair_recall": float(fair.detected.mean()) if len(fair) else float("nan")})
    return pd.DataFrame(rows)
