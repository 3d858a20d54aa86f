"""The bird's-eye-view figure of docs/slots.md (docs/img/bev.png): `python -m benchmarks.figures.bev [--plan tiny]
[--shot 0] [--out docs/img/bev.png] [OVERRIDE ...]`.

One shot of `camera=fisheye4 case=slots`, rendered: the four fisheye pictures (left, 2x2), the BEV stitched from
them with the seams between cameras (magenta, middle), and the same BEV with the ground-truth slots (red
occupied, green free; white dots: marking points, filled T, hollow L; a tick along the direction into the slot);
where the config has a `slot_detector`, its slots in light blue. Prints each slot's visibility and fairness.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmarks import jobkit
import numpy as np


def label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    img = img.copy()
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
    cv2.rectangle(img, (0, 0), (w + 10, h + 10), (0, 0, 0), -1)
    cv2.putText(img, text, (5, h + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1, cv2.LINE_AA)
    return img


def main() -> None:
    import cv2
    from PIL import Image

    from garage_exp.slots.export import draw_frame
    from garage_exp.slots.truth import obstacles, slot_truth, world_bays
    from garage_exp.plan import classify, load_plan
    from garage_exp.render.bev import bev_maps
    from garage_exp.run.preflight import resolve_plan_path
    from garage_exp.run.spec import scene_spec
    from garage_exp.scenario.assemble import marking_wear
    from garage_exp.slots.frames import bev_spec, finder

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", default="tiny")
    parser.add_argument("--shot", type=int, default=0)
    parser.add_argument("--out", default="docs/img/bev.png")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    motion = ["case.motion.start=3.0", "case.motion.end=5.0", "case.motion.step=1.0"] if args.plan == "tiny" else []
    job = jobkit.build_job([f"plan={args.plan}", "camera=fisheye4", "case=slots", "renderer.save_frames=none",
                            *motion, *args.overrides])
    cfg, scene = job.cfg, job.scene
    frames = [f for f in job.frames(args.shot + 1) if f.shot.index == args.shot]
    pictures = {f.camera: f.rgb for f in frames}
    shot = frames[0].shot
    ego = next(v for v in scene.vehicles() if v.role == "ego")
    spec = bev_spec(cfg)
    maps = bev_maps(scene.cameras, spec, ego.extent)
    bev = maps.stitch(pictures)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    wear = marking_wear(scene_spec(cfg))
    truth = slot_truth(world_bays(classified, cfg.garage, wear), spec, shot.ego, scene.cameras, maps,
                       obstacles(scene, shot.poses))
    seamed = bev.copy()
    seamed[maps.seams] = (255, 0, 255)
    drawn = draw_frame(bev, truth.frame, thickness=1)
    found_by = finder(cfg.slot_detector)
    if found_by is not None:
        found = found_by[0](bev, spec.meters_per_pixel)
        drawn = draw_frame(drawn, found, colour=(80, 200, 255), thickness=1)
        print("detector:", found_by[1](truth.frame, found, truth.fair, found_by[3]))
    for slot, vis, fair in zip(truth.frame.slots, truth.visibility, truth.fair):
        print(f"{slot.bay}: occupied={slot.occupied} corners={vis} fair={fair}")
    h = 480
    tiles = [label(cv2.resize(pictures[c.name], (320, 240), interpolation=cv2.INTER_AREA), f"fisheye {c.name}")
             for c in scene.cameras]
    left = np.vstack([np.hstack(tiles[0:2]), np.hstack(tiles[2:4])])
    size = (int(round(bev.shape[1] * h / bev.shape[0])), h)
    middle = label(cv2.resize(seamed, size, interpolation=cv2.INTER_AREA),
                   f"BEV {spec.width:g} x {spec.length:g} m at {spec.meters_per_pixel:g} m/px; seams magenta")
    right = label(cv2.resize(drawn, size, interpolation=cv2.INTER_AREA),
                  "truth slots (red occupied, green free)" + (", detections blue" if found_by else ""))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.hstack([left, middle, right])).save(args.out)
    print(args.out)


if __name__ == "__main__":
    main()
