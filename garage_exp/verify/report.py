"""The short report of a verification: what was scored, the numbers, and what they mean for simulation."""

from __future__ import annotations

from pathlib import Path

from garage_exp.verify.data import LabelledSet
from garage_exp.verify.score import HEIGHT_BINS, Scored, height_band

GOOD = 0.5  # below this recall or mAP50 on real images, a detector's simulated scores say little
CAVEAT = ("Synthetic results are only meaningful for a detector that is good on real images of the same classes: "
          "a detector that misses real vehicles and people scores low in every simulated garage for its own "
          "reasons, and no factor's effect can be read from its scores.")


def verdict(metrics: dict[str, float], rendered: bool = False) -> str:
    recall, ap = metrics["recall"], metrics["map50"]
    if rendered:
        return (f"These are rendered images (recall {recall:.2f}, mAP50 {ap:.2f}): simulation results, not a check "
                "on real images. Score the detector on a labelled set of real photos too.")
    if recall >= GOOD and ap >= GOOD:
        return (f"Good on these real images (recall {recall:.2f}, mAP50 {ap:.2f}, both >= {GOOD}): its simulated "
                "results can be read as the effect of the garage, for these classes.")
    return (f"Weak on these real images (recall {recall:.2f}, mAP50 {ap:.2f}; {GOOD} or more expected): fix or "
            "replace the detector before reading its simulated results.")


def write_report(path: Path, data: LabelledSet, detector_name: str, scored: Scored, metrics: dict[str, float],
                 threshold: float, iou: float) -> Path:
    obj = scored.objects
    kinds = ", ".join(f"{k} {int(metrics['targets/' + k])}" for k in ("vehicle", "person") if "targets/" + k in metrics)
    ignored = ", ".join(f"{k} {n}" for k, n in sorted(scored.ignored.items()))
    what = "rendered" if data.rendered else "real"
    lines = [f"# Detector check on {what} images: {detector_name}", "",
             f"Data: `{data.source}` ({data.format.upper()}), {len(data.images)} images, {len(obj)} labelled objects "
             f"of the scored classes ({kinds})." + (f" Not scored (classes the project does not score): {ignored}."
                                                     if ignored else ""),
             "", f"**{verdict(metrics, data.rendered)}**", "", CAVEAT, "",
             f"A labelled object is found when a detection of its kind overlaps it with IoU >= {iou}; its confidence "
             f"is the models' mean (0 when missed), recall the share reaching {threshold}. False positives per image: "
             "confident detections (>= 0.25) matching no labelled object of their kind, or of another class, as in "
             "a job's frame table. mAP50: COCO's AP at IoU 0.5 (pycocotools) over vehicle and person.", "",
             "| model | recall | mean confidence | mAP50 | false positives per image |", "|---|---|---|---|---|"]
    for m in scored.models:
        lines.append(f"| {m} | {metrics[f'recall/{m}']:.3f} | {metrics[f'mean_confidence/{m}']:.3f} | "
                     f"{metrics[f'map50/{m}']:.3f} | {metrics[f'fp_per_image/{m}']:.2f} |")
    lines.append(f"| **composite** | **{metrics['recall']:.3f}** | **{metrics['mean_confidence']:.3f}** | "
                 f"**{metrics['map50']:.3f}** | **{metrics['fp_per_image']:.2f}** |")
    lines += ["", "Confidence by box height (the labelled box's height in pixels):", "",
              "| box height | objects | mean confidence | recall |", "|---|---|---|---|"]
    for lo, hi in zip(HEIGHT_BINS[:-1], HEIGHT_BINS[1:]):
        band = height_band(lo, hi)
        if f"recall_by_height/{band}" in metrics:
            n = int(((obj.box_height >= lo) & (obj.box_height < hi)).sum())
            lines.append(f"| {band} | {n} | {metrics[f'confidence_by_height/{band}']:.3f} | "
                         f"{metrics[f'recall_by_height/{band}']:.3f} |")
    lines += ["", "Each object's confidences: `objects.csv`; each image's false positives: `images.csv`.", ""]
    path.write_text("\n".join(lines))
    return path
