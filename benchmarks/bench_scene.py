"""Scene build time against plan size: `python benchmarks/bench_scene.py [--sizes 10 20 40 60] [--repeat 3]`.

Plans are generated: a lane every third row and column, bays between, an entrance on the west edge.
Classification is timed apart from the build (it is cached per plan in a real run). Prints a table with the
time per cell and the ratio to the smallest plan; a linear builder keeps the time per cell flat.
"""

from __future__ import annotations

import argparse
import time

from garage_exp.config import GarageConf, LightConf
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
    args = parser.parse_args()
    garage, light = GarageConf(), LightConf()
    print(f"{'plan':>8} {'cells':>6} {'classify s':>10} {'build s':>8} {'us/cell':>8} {'ratio':>6} "
          f"{'entities':>8} {'boxes':>6} {'lights':>6}")
    base = None
    for n in args.sizes:
        plan = grid_plan(n)
        t0 = time.perf_counter()
        classified = classify(plan)
        t_classify = time.perf_counter() - t0
        t_build = best_of(args.repeat, lambda: build_garage(classified, garage, light))
        scene = build_garage(classified, garage, light)
        base = base if base is not None else t_build
        boxes = sum(len(e.shapes) for e in scene.entities)
        print(f"{n:>3} x {n:<3} {n * n:>6} {t_classify:>10.3f} {t_build:>8.3f} {1e6 * t_build / (n * n):>8.1f} "
              f"{t_build / base:>6.1f} {len(scene.entities):>8} {boxes:>6} {len(scene.lights):>6}")


if __name__ == "__main__":
    main()
