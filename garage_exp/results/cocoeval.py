"""COCO's AP at IoU 0.5 (pycocotools' COCOeval), for the loop's held-out suites and `garage_exp.verify`."""

from __future__ import annotations

import contextlib
import io


def ap50(gt: dict, detections: list[dict]) -> float:
    """AP50 over the categories of `gt` (a COCO dict: images, annotations, categories) that have annotations,
    for `detections` ({image_id, category_id, bbox xywh, score}); 0.0 without annotations or detections."""
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    if not gt["annotations"] or not detections:
        return 0.0
    with contextlib.redirect_stdout(io.StringIO()):  # COCOeval prints its whole table
        ground = COCO()
        ground.dataset = gt
        ground.createIndex()
        ev = COCOeval(ground, ground.loadRes(detections), "bbox")
        ev.evaluate()
        ev.accumulate()
        ev.summarize()
    return float(max(ev.stats[1], 0.0))  # -1 means no ground truth of any category evaluated
