"""The frames of the camera rigs in docs/configuration.md (docs/img/rigs_*.png):
`python -m benchmarks.figures.rig_frames [--out docs/img]`.

- rigs_mounts.png: case 1 from each forward mount (rows) at 30, 60, 90 and 120 degrees vertical FOV (columns),
  plus the legacy `camera=front` and the rear and side-mirror mounts.
- rigs_fisheye4.png: the four fisheye cameras of `camera=fisheye4` at one shot of case 2, ground truth boxes.
- rigs_views.png: case 2's passing car through the front fisheye, raw and undistorted (`camera.view`).
- rigs_surround.png: the four pinhole cameras of `camera=surround` at the same shot of case 2.
Each tile is labelled; green boxes are ground truth (full box of the target).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from benchmarks import jobkit
import numpy as np

TILE = (320, 240)


def shot_frames(overrides: list[str], shot: int) -> list:
    job = jobkit.build_job(["renderer.save_frames=none", "palette.target_colours=[black]", *overrides])
    job.setup = replace(job.setup, shots=job.setup.shots[shot:shot + 1])
    return list(job.frames())


def tile(frame, label: str) -> np.ndarray:
    import cv2

    img = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR).copy()
    if frame.target is not None:
        x1, y1, x2, y2 = frame.target.full_box
        cv2.rectangle(img, (x1, y1), (x2, y2), (0, 255, 0), 2)
    img = cv2.resize(img, TILE, interpolation=cv2.INTER_AREA)
    (w, h), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
    cv2.rectangle(img, (0, 0), (w + 10, h + 10), (0, 0, 0), -1)
    cv2.putText(img, label, (5, h + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 255), 1, cv2.LINE_AA)
    return img


def grid(tiles: list[np.ndarray], columns: int) -> np.ndarray:
    blank = np.zeros_like(tiles[0])
    tiles = tiles + [blank] * (-len(tiles) % columns)
    return np.vstack([np.hstack(tiles[k:k + columns]) for k in range(0, len(tiles), columns)])


def main() -> None:
    import cv2

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/img")
    parser.add_argument("--surround-only", action="store_true", help="write rigs_surround.png only")
    args = parser.parse_args()
    out = Path(args.out)
    frames = shot_frames(["case=2", "camera=surround"], 24)
    cv2.imwrite(str(out / "rigs_surround.png"), grid([tile(f, f"surround: {f.camera}") for f in frames], 2))
    if args.surround_only:
        return
    tiles = []
    for mount in ("roof", "mirror", "bumper"):
        for fovy in (30, 60, 90, 120):
            (frame,) = shot_frames(["case=1", f"camera.mount={mount}", f"camera.fovy={fovy}"], 20)
            tiles.append(tile(frame, f"{mount}, fovy {fovy}"))
    for label, overrides in (("front (legacy roof), fovy 60", []),
                             ("rear, fovy 90", ["camera.mount=rear", "camera.fovy=90"]),
                             ("left_mirror, fovy 90", ["camera.mount=left_mirror", "camera.fovy=90"]),
                             ("right_mirror, fovy 90", ["camera.mount=right_mirror", "camera.fovy=90"])):
        (frame,) = shot_frames(["case=1", *overrides], 20)
        tiles.append(tile(frame, label))
    cv2.imwrite(str(out / "rigs_mounts.png"), grid(tiles, 4))
    frames = shot_frames(["case=2", "camera=fisheye4"], 24)
    cv2.imwrite(str(out / "rigs_fisheye4.png"), grid([tile(f, f"fisheye4: {f.camera}") for f in frames], 2))
    tiles = []
    for shot in (6, 22):
        for view in ("raw", "perspective", "cylindrical"):
            (frame,) = shot_frames(["case=2", "camera=fisheye", f"camera.view={view}"], shot)
            angle = f", {frame.target.off_axis:.0f} deg off axis" if frame.target else ""
            tiles.append(tile(frame, f"{view}{angle}"))
    cv2.imwrite(str(out / "rigs_views.png"), grid(tiles, 3))


if __name__ == "__main__":
    main()
