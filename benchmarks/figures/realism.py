"""docs/img/realism.png: the same shots under the flat and the real look, each materials level, and close views
of a car's contact shadow and of a person. `python -m benchmarks.figures.realism [--out docs/img/realism.png]`.

Frames are what the detectors get (after the sensor model): the flat look with the ideal camera, the real look
with the real camera.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("TQDM_DISABLE", "1")

from benchmarks import jobkit  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

AHEAD = ["case=light", "case.motion.values=[10.0]", "palette.target_colours=[white]"]
PROBE = ["case=light", "case.motion.values=[6.0]"]
PERSON = ["case=pedestrian", "case.motion.start=1.0", "case.motion.end=1.0", "case.variants=[{label: adult,"
          " show: [adult, car_left, car_right, car_before1, car_before2], target: adult, set: {ego.distance: 6.0,"
          " ego.before: adult}}]"]


def frame(overrides: list[str], shot: int = 0):
    job = jobkit.build_job(overrides)
    for k, rendered in enumerate(job.frames(shot + 1)):
        if k == shot:
            return rendered.rgb, rendered.target


def crop(rgb, target, pad: float = 0.35):
    x1, y1, x2, y2 = target.full_box
    w, h = x2 - x1, y2 - y1
    return rgb[max(0, int(y1 - pad * h)):int(y2 + pad * h), max(0, int(x1 - pad * w)):int(x2 + pad * w)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(jobkit.PROJECT_ROOT / "docs" / "img" / "realism.png"))
    args = parser.parse_args()
    panels = [("flat look (ideal camera)", frame([*AHEAD, "look=flat"])[0])]
    for level in ("clean", "worn", "wet", "random"):
        panels.append((f"real look, materials={level}", frame([*AHEAD, f"materials={level}"])[0]))
    rgb, target = frame([*PROBE, "look=flat"])
    panels.append(("flat: a car at 6 m", crop(rgb, target)))
    rgb, target = frame(PROBE)
    panels.append(("real: the same car, its contact shadow", crop(rgb, target)))
    rgb, target = frame(PERSON)
    panels.append(("real: a person stepping out", crop(rgb, target, pad=0.6)))
    fig, axes = plt.subplots(2, 4, figsize=(16, 7.2))
    for ax, (title, image) in zip(axes.flat, panels):
        ax.imshow(image)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.suptitle("The lighting case, a white car 10 m ahead (top row, first of the bottom row), and close views",
                 fontsize=12)
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
    print(args.out)


if __name__ == "__main__":
    main()
