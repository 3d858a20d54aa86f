"""Scene build time against plan size: `python -m benchmarks.performance.scene [--sizes 10 20 40 60] [--repeat 3]`.

Plans are generated: a lane every third row and column, bays between, an entrance on the west edge.
Classification is timed apart from the build (it is cached per plan in a real run). Prints a table with the
time per cell and the ratio to the smallest plan; a linear builder keeps the time per cell flat. `load s` is
the SAPIEN scene made from the description (`renderer.load`, no frame rendered; `--no-render` skips it).

Target (issue 6): a 60x60-cell plan builds in under 1 s (description + SAPIEN load), about linearly in cells.
"""

from __future__ import annotations

import argparse
import time

from benchmarks import jobkit

from garage_exp.scene.schema import GarageConf, LightConf
from garage_exp.plan import classify, plan_from_lists
from garage_exp.plan.model import Plan
from garage_exp.scene.structure import build_garage


def grid_plan(n: int) -> Plan:
    lane = lambda k: k % 3 == 1  # noqa: E731
    S = [[1 if lane(i) or lane(j) else 0 for j in range(n)] for i in range(n)]
    S[1][0] = 2
    R = [6.0 if lane(i) else 5.0 for i in range(n)]
    C = [6.0 if lane(j) else 7.5 for j in range(n)]
    return plan_from_lists(S, R, C, f"grid{n}")


def best_of(repeat: int, fn) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 20, 40, 60])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-render", action="store_true", help="time the description only")
    args = parser.parse_args()
    renderer = None
    if not args.no_render:
        from garage_exp.render.sapien_backend import get_renderer

        renderer = get_renderer()
        renderer.load(build_garage(classify(grid_plan(4)), GarageConf(), LightConf()))  # Vulkan start-up
    print(f"# {jobkit.machine()}; {jobkit.load()}")
    garage, light = GarageConf(), LightConf()
    print(f"{'plan':>8} {'cells':>6} {'classify s':>10} {'build s':>8} {'load s':>7} {'us/cell':>8} {'ratio':>6} "
          f"{'entities':>8} {'boxes':>6} {'lights':>6}")
    base, total = None, 0.0
    for n in args.sizes:
        plan = grid_plan(n)
        t0 = time.perf_counter()
        classified = classify(plan)
        t_classify = time.perf_counter() - t0
        t_build = best_of(args.repeat, lambda: build_garage(classified, garage, light))
        scene = build_garage(classified, garage, light)
        t_load = best_of(args.repeat, lambda: renderer.load(scene)) if renderer else 0.0
        total = t_build + t_load
        per_cell = total / (n * n)
        base = base if base is not None else per_cell
        boxes = sum(len(e.shapes) for e in scene.entities)
        print(f"{n:>3} x {n:<3} {n * n:>6} {t_classify:>10.3f} {t_build:>8.3f} {t_load:>7.3f} {1e6 * per_cell:>8.1f} "
              f"{per_cell / base:>6.2f} {len(scene.entities):>8} {boxes:>6} {len(scene.lights):>6}")
    n = args.sizes[-1]
    print(f"# {n}x{n}: build + load {total:.2f} s (target < 1 s: {'met' if total < 1.0 else 'NOT met'}); "
          f"time per cell {per_cell / base:.2f}x the {args.sizes[0]}x{args.sizes[0]} plan's (1.0 = linear)")


if __name__ == "__main__":
    main()
