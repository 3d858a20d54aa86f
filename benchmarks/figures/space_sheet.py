"""A contact sheet of random draws of a shipped search space (docs/img/space_wide.png):
`python -m benchmarks.figures.space_sheet [--space wide] [--draws 24] [--seed 0] [--out docs/img]`.

Each draw is a point of the space's `params` drawn by Optuna's random sampler (as `search.sampler=random`
draws it), composed with the space's other overrides, checked and its scene built as a job's preflight does
(a generated garage's own ceiling and pillars included), and one frame rendered at 320x240 through the sensor. A
draw whose actors stand in one another (core.errors.Infeasible) is redrawn, as the search prunes it, and so is
one the space's requirements reject (search/require.py), as the search redraws it; both rates are printed. Tiles are labelled with the target's type, distance and the light; the green
box is the target's full box (ground truth).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks import jobkit
from benchmarks.figures.rig_frames import grid, tile

SIZE = ["camera.width=320", "camera.height=240", "renderer.save_frames=none"]


def space_of(name: str):
    """The space's Space (search/space.py) as a search with `space=NAME` and no other override builds it."""
    from garage_exp.search import space as space_mod

    cfg = jobkit.compose([f"space={name}"])
    return cfg, space_mod.build(space_mod.expand(cfg, [f"space={name}"]), cfg, {})


def draws(space, count: int, seed: int):
    """Random points of the space, one after another (an endless stream: infeasible ones are skipped)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed))
    while True:
        yield study.ask(space.params).params


def label(values: dict) -> str:
    kind = values.get("case.actors.target.type", "?")
    return (f"{kind} {values.get('case.actors.target.distance', 0):.0f}m "
            f"{values.get('light.temperature', 0):.0f}K x{values.get('light.intensity', 0):.1f}")


def main() -> None:
    import cv2

    from garage_exp.core.errors import Infeasible

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--space", default="wide")
    parser.add_argument("--draws", type=int, default=24)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="docs/img")
    args = parser.parse_args()
    _, space = space_of(args.space)
    from garage_exp.search import require as require_mod

    cfg, _ = space_of(args.space)
    space_mod_settle(cfg, args.space)
    rule = require_mod.Require.of(cfg.search.require)
    tiles, tried, feasible, t0 = [], 0, 0, time.perf_counter()
    for values in draws(space, args.draws, args.seed):
        if len(tiles) == args.draws:
            break
        tried += 1
        try:
            job = jobkit.prepared_job([*space.overrides(values), *SIZE])
        except Infeasible as exc:
            print(f"draw {tried}: infeasible ({exc})")
            continue
        feasible += 1
        if rule is not None:
            verdict = require_mod.judge(rule, job.scene, job.setup, job.scene.cameras[0].name)
            if not verdict.ok:
                print(f"draw {tried}: rejected by the requirements ({verdict.why})")
                continue
        frame = next(iter(job.load().frames(1)))
        tiles.append(tile(frame, label(values)))
        print(f"draw {tried}: {label(values)}  visible {getattr(frame.target, 'visible_fraction', float('nan')):.2f}")
    out = Path(args.out) / f"space_{args.space}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), grid(tiles, 6)):  # OpenCV says a failed write only by its return value
        raise SystemExit(f"{out}: not written")
    print(f"{out}: {len(tiles)} draws of {tried}: {feasible} feasible ({feasible / tried:.0%}), "
          f"{len(tiles)} of those accepted by the requirements ({len(tiles) / max(feasible, 1):.0%}); "
          f"{time.perf_counter() - t0:.0f} s, {jobkit.machine()}")


def space_mod_settle(cfg, name: str) -> None:
    """The space's requirements onto the config's search node, as the search settles them."""
    from garage_exp.search import space as space_mod

    space_mod.settle(cfg, [f"space={name}"])


if __name__ == "__main__":
    main()
