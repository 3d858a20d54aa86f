"""The `lines` slot-detector baseline scored on synthetic bird's-eye views (garage_exp/slots/synthetic.py):
`python -m benchmarks.studies.slot_detector [--frames 40] [--png docs/img/slot_detector.png]`.

Each condition is the same `--frames` seeds (the same layouts, cars and noise draws), drawn with the bay lines
alone (as the project's garage paints them) or with an entrance line too (PS2.0's T and L marks), fresh or
worn (wear 0.7: paint faded 42 % towards the floor, each 0.25 m piece gone with probability 0.35), in bright or
dim light (gain 0.35, the same noise). Rates are pooled over frames with a 95 % frame-bootstrap interval
(results.stats.ratio_ci, a frame's points resampled together). Prints a markdown table; --png saves one worn
frame with the truth (green) and the detections (magenta) drawn.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from garage_exp.slots.schema import SlotDetectorConf
from garage_exp.slots.detector import load
from garage_exp.slots.synthetic import bev_row
from garage_exp.slots.results import pool, score
from garage_exp.results.stats import ratio_ci

CONDITIONS = {  # name -> bev_row settings
    "fresh, bright": {},
    "worn, bright": {"wear": 0.7},
    "fresh, dim": {"gain": 0.35},
    "worn, dim": {"wear": 0.7, "gain": 0.35},
}


def interval(frames: list[dict], hit: str, miss: str) -> str:
    values, clusters = [], []
    for k, m in enumerate(frames):
        values += [1.0] * int(m[hit]) + [0.0] * int(m[miss])
        clusters += [k] * (int(m[hit]) + int(m[miss]))
    mean, low, high, _ = ratio_ci(values, clusters)
    return f"{mean:.2f} ({low:.2f}-{high:.2f})"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--png", default="")
    args = ap.parse_args()
    from omegaconf import OmegaConf

    conf = OmegaConf.structured(SlotDetectorConf)
    detect = load(conf)
    print("| paint | condition | point precision | point recall | slot precision | slot recall | occupancy "
          "| point error (m) | ms/frame |")
    print("|---|---|---|---|---|---|---|---|---|")
    for entrance in (False, True):
        for name, settings in CONDITIONS.items():
            frames, spent = [], 0.0
            for seed in range(args.frames):
                image, truth = bev_row(seed, entrance_line=entrance, **settings)
                start = time.perf_counter()
                found = detect(image, truth.meters_per_pixel)
                spent += time.perf_counter() - start
                frames.append(score(truth, found, None, conf.metrics))
            p = pool(frames)
            print(f"| {'with entrance line' if entrance else 'bay lines only'} | {name} "
                  f"| {interval(frames, 'point_tp', 'point_fp')} | {interval(frames, 'point_tp', 'point_fn')} "
                  f"| {interval(frames, 'slot_tp', 'slot_fp')} | {interval(frames, 'slot_tp', 'slot_fn')} "
                  f"| {p['occupancy_accuracy']:.2f} of {int(p['occupancy_n'])} | {p['point_error_m']:.3f} "
                  f"| {1000 * spent / args.frames:.0f} |")
    if args.png:
        save_png(args.png, detect)


def save_png(path: str, detect) -> None:
    """Frame 1 fresh and worn, the truth (green) and the detections (magenta) drawn, each cropped to the half of
    the image that holds the bays and shrunk to 80 %."""
    import cv2

    from garage_exp.slots.draw import TRUTH, draw_slots

    panels = []
    for label, settings in (("fresh", {}), ("worn 0.7", {"wear": 0.7})):
        image, truth = bev_row(1, **settings)
        drawn = draw_slots(draw_slots(image, truth, TRUTH), detect(image, truth.meters_per_pixel))
        centre = np.mean([c for s in truth.slots for c in s.corners], axis=0)
        h, w = image.shape[:2]
        if abs(centre[0] - w / 2) > abs(centre[1] - h / 2):  # the bays lie left or right: keep that half
            drawn = drawn[:, : w // 2] if centre[0] < w / 2 else drawn[:, w // 2:]
        else:
            drawn = drawn[: h // 2] if centre[1] < h / 2 else drawn[h // 2:]
        drawn = np.ascontiguousarray(drawn)
        cv2.putText(drawn, label, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2, cv2.LINE_AA)
        panels.append(drawn)
    out = cv2.resize(np.concatenate(panels, axis=1), None, fx=0.8, fy=0.8, interpolation=cv2.INTER_AREA)
    cv2.imwrite(path, out[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {path}")

if __name__ == "__main__":
    main()
