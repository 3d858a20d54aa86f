"""Which factor puts the blank control below the garage (issue 47, item 12): each candidate changed alone, mean
composite confidence per light preset and target colour. `python -m benchmarks.studies.blank_factors
[--replicates 3] [--frames DIR]`.

The light case (black and white medium cars 6-12 m ahead) is rendered four ways per preset: in the garage, as the
blank scene (the vehicles alone), as the garage with everything but the floor removed, and the same with the
cars' contact shadows. The variants below are made from those renders; the sensor (the real look's `camera`) gets a
fresh stream per frame, seeded by the frame's number, so that variants differ only in their pixels.

  garage            the garage frame through the camera (the light table's garage cell)
  blank (old)       the target on grey 128, then the camera (the blank cell before this study)
  grey 64 / 192     the same on a darker / lighter grey
  garage's AE       the blank with the exposure and gain the camera chose for the garage frame
  ideal camera      the blank on grey 128 with no camera at all (no AE, tone curve, blur or noise)
  cut from garage   the garage frame through the camera, then everything but the target's pixels grey 128:
                    the car exactly as the garage frame shows it, its surroundings removed
  floor             the target on the bare floor (no walls, pillars, ceiling, lamps' fixtures), rest grey 128
  floor + shadow    the same with its contact shadow
  bright's light    the blank (old) rendered under the bright preset whatever the cell's preset (the lighting of
                    the car alone changed)
  shadow            the blank (old) with the target's contact shadow on the grey (render.composite.contact_shadow)
  studio light      the blank (old) under the real look's `blank_light` (the studio: every lamp, ambient 0.3)
  blank (new)       the blank control as the pipeline now makes it: studio light and contact shadow
"""

from __future__ import annotations

import argparse
import os
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("TQDM_DISABLE", "1")

import numpy as np  # noqa: E402

from benchmarks import jobkit  # noqa: E402

PRESETS = ("bright", "clear", "moderate", "dim")
COLOURS = ("black", "white")


def raw_takes(job):
    """Each shot's front frame as rendered (no camera model): (shot, rgb, ids, target mask, ego id, truth,
    target's truth, frame, the renderer's name -> id map)."""
    from garage_exp.perception.groundtruth import ground_truth
    from garage_exp.run.pipeline import in_view

    pipe = job.pipeline()
    shots = job.setup.shots
    out = []
    for start in range(0, len(shots), pipe.stage.n):
        batch = shots[start:start + pipe.stage.n]
        actors = [in_view(job.scene, shot.poses) for shot in batch]
        for take in pipe.stage.render_batch(batch, ["front"], actors, pipe.redress):
            truth = ground_truth(take.frame, take.silhouettes, job.scene, take.ids)
            target = next((t for t in truth if t.name == take.shot.target), None)
            mask = take.frame.ids == take.ids[take.shot.target]
            frame = replace(take.frame, rgb=take.frame.rgb.copy(), ids=take.frame.ids.copy())
            out.append((take.shot, frame.rgb, frame.ids, mask, take.ids.get("ego", -1), truth, target, frame,
                        dict(take.ids)))
    return out


def on_grey(rgb, keep, level=128):
    out = np.full_like(rgb, level)
    out[keep] = rgb[keep]
    return out


def fixed_ae(sensor, choice):
    """The sensor with its auto-exposure pinned to `choice` (exposure, gain)."""
    pinned = replace(sensor)
    object.__setattr__(pinned, "exposure_and_gain", lambda mean: choice)
    return pinned


def strip(shadows: bool):
    """A scene edit: everything but the vehicles and the floor removed (the cars' contact shadows kept or not)."""
    from garage_exp.scene.description import Decal

    def edit(scene):
        scene.entities = [e for e in scene.entities if e.role in ("target", "ego") or e.name.startswith("floor_")]
        if not shadows:
            for e in scene.entities:
                e.shapes = [sh for sh in e.shapes if not isinstance(sh, Decal)]
    return edit


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicates", type=int, default=3)
    parser.add_argument("--presets", default=",".join(PRESETS))
    parser.add_argument("--frames", default="", help="a folder for each variant's frames of replicate 0 (PNG)")
    parser.add_argument("--only", default="", help="comma-separated variants (default: all)")
    parser.add_argument("--figure", default="", help="only draw docs/img/blank_control.png from --frames' PNGs")
    args = parser.parse_args()
    if args.figure:
        figure(Path(args.frames), Path(args.figure))
        return
    from PIL import Image

    from garage_exp.core.plugins import build
    from garage_exp.perception.detect.detector import build_detector
    from garage_exp.perception.detect.matching import Scoring
    from garage_exp.render.composite import blank_composite, contact_shadow
    from garage_exp.render.sapien_backend import get_renderer

    base = ["case=light", f"replicates={args.replicates}"]
    presets = args.presets.split(",")
    only = set(args.only.split(",")) if args.only else None
    wanted = lambda name: only is None or name in only  # noqa: E731
    frames_dir = Path(args.frames) if args.frames else None
    if frames_dir:
        frames_dir.mkdir(parents=True, exist_ok=True)
    scores: dict[tuple, list[float]] = {}
    detector = None
    old = ["blank=true", "look.blank_light=null"]  # the blank before this study: lit by the cell's preset
    bright_blank = raw_takes(jobkit.build_job([*base, "light=bright", *old])) if wanted("bright's light") else None
    studio_job = jobkit.build_job([*base, "light=bright", "blank=true"])
    studio = raw_takes(studio_job)
    for preset in presets:
        over = [*base, f"light={preset}"]
        garage = jobkit.build_job(over)
        cfg = garage.cfg
        if detector is None:
            detector = build_detector(cfg.detector)
            rule, classes = Scoring.of(cfg.detector), detector.scoring()
        sensor = build(cfg.sensor, "a sensor model", "sensor._target_")
        g = raw_takes(garage)
        blank_job = jobkit.build_job([*over, *old])
        b = raw_takes(blank_job)
        floors = {}
        for name, shadows in (("floor", False), ("floor + shadow", True)):
            if wanted(name):
                renderer = get_renderer()
                renderer.batch_static = False  # the floor gets ids of its own: id 0 is then only empty space
                try:
                    floors[name] = raw_takes(jobkit.build_job(over, strip(shadows)))
                finally:
                    renderer.batch_static = True

        for k, (shot, rgb, ids, mask, ego, truth, target, *_) in enumerate(g):
            colour = shot.label  # the palette colour (a replicate's target is named target_black_r1)
            rng = lambda: np.random.default_rng([7, k])  # noqa: E731 - the same noise draw for every variant
            brgb, bmask = b[k][1], b[k][3]
            choice = sensor.expose(rgb[None])[1][0]
            variants = {
                "garage": lambda: sensor.apply(rgb, rng()),
                "blank (old)": lambda: sensor.apply(on_grey(brgb, bmask), rng()),
                "grey 64": lambda: sensor.apply(on_grey(brgb, bmask, 64), rng()),
                "grey 192": lambda: sensor.apply(on_grey(brgb, bmask, 192), rng()),
                "garage's AE": lambda: fixed_ae(sensor, choice).apply(on_grey(brgb, bmask), rng()),
                "ideal camera": lambda: on_grey(brgb, bmask),
                "cut from garage": lambda: on_grey(sensor.apply(rgb, rng()), mask),
            }
            if bright_blank is not None:
                variants["bright's light"] = lambda: sensor.apply(on_grey(bright_blank[k][1], bright_blank[k][3]),
                                                                  rng())
            for name, takes in floors.items():
                _, frgb, fids, _, fego, *_ = takes[k]
                variants[name] = (lambda frgb=frgb, keep=(fids != 0) & (fids != fego):
                                  sensor.apply(on_grey(frgb, keep), rng()))
            shadow = contact_shadow(b[k][7], blank_job.scene.entity(shot.target), b[k][7].poses[shot.target])
            variants["shadow"] = lambda: sensor.apply(blank_composite(brgb, b[k][7], b[k][8], [shot.target], shadow),
                                                      rng())
            variants["studio light"] = lambda: sensor.apply(on_grey(studio[k][1], studio[k][3]), rng())
            variants["blank (new)"] = lambda: sensor.apply(
                blank_composite(studio[k][1], studio[k][7], studio[k][8], [shot.target], shadow), rng())
            for name, make in variants.items():
                if not wanted(name):
                    continue
                image = make()
                score = rule.score(detector.detect([image])[0], target, truth, **classes).composite
                scores.setdefault((name, colour, preset), []).append(score)
                if frames_dir and k < 8:
                    Image.fromarray(image).save(frames_dir / f"{preset}_{k:02d}_{slug(name)}.png")
        print(f"# {preset} done", flush=True)
    names = list(dict.fromkeys(n for n, _, _ in scores))
    print(f"\n# mean composite, {args.replicates} replicates x 4 distances a cell; {jobkit.machine()}")
    print("| variant | colour | " + " | ".join(presets) + " |")
    print("|---|---|" + "---|" * len(presets))
    for name in names:
        for colour in COLOURS:
            cells = [np.mean(scores[(name, colour, p)]) for p in presets]
            print(f"| {name} | {colour} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")


FIGURE = ("garage", "blank (old)", "studio light", "blank (new)")


def slug(name: str) -> str:
    return name.replace(" ", "_").replace("'", "").replace("+", "and").replace("(", "").replace(")", "")


def figure(frames: Path, out: Path) -> None:
    """The black and white car 8 m ahead (replicate 0) in bright and dim light: the middle of each variant's
    frame, side by side (FIGURE's variants), as the detectors got it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    shots = [("bright", 1, "black"), ("dim", 1, "black"), ("bright", 5, "white"), ("dim", 5, "white")]
    fig, axes = plt.subplots(len(shots), len(FIGURE), figsize=(3.2 * len(FIGURE), 2.3 * len(shots)))
    for row, (preset, k, colour) in enumerate(shots):
        for col, name in enumerate(FIGURE):
            image = np.asarray(Image.open(frames / f"{preset}_{k:02d}_{slug(name)}.png"))
            ax = axes[row, col]
            ax.imshow(image[190:370, 180:460])
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(name, fontsize=10)
            if col == 0:
                ax.set_ylabel(f"{colour}, {preset}", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=60)
    print(out)


if __name__ == "__main__":
    main()
