"""`python -m garage_exp.plan map PLAN_FILE [-o out.png]` draws a plan; `... check PLAN_FILE` summarises it;
`... generate [-o DIR]` writes the generated big garages (plan/generate.py) into plans/.
Bad input prints the one-line GarageError to stderr and exits 2."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from garage_exp.core import shell
from garage_exp.plan.classify import LANE_TYPES, PARKING_TYPES, Classified, classify
from garage_exp.plan.load import load_plan


def summary(classified: Classified) -> str:
    """A few lines: size, cell counts by kind and type, pillars."""
    plan = classified.plan
    m, n = plan.shape
    width, depth = plan.size
    kinds = Counter(c.kind for c in classified.all_cells())
    types = Counter((c.kind, c.type) for c in classified.all_cells())
    lanes = ", ".join(f"{t} {types['lane', t]}" for t in LANE_TYPES)
    bays = ", ".join(f"{t} {types['parking', t]}" for t in PARKING_TYPES)
    return "\n".join([
        f"plan {plan.name} ({plan.source})",
        f"size: {m} x {n} cells, {width:.1f} x {depth:.1f} m (x by y)",
        f"lanes: {kinds['lane']} ({lanes})",
        f"parking: {kinds['parking']} ({bays})",
        f"entrances: {kinds['entrance']}, exits: {kinds['exit']}, obstacles: {kinds['obstacle']}",
        f"pillars: {len(classified.pillars)}",
    ])


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m garage_exp.plan", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    draw = sub.add_parser("map", help="draw a top-down PNG map of the plan")
    draw.add_argument("plan_file", type=Path, metavar="PLAN_FILE")
    draw.add_argument("-o", "--output", type=Path, help="PNG to write (default: PLAN_map.png here)")
    check = sub.add_parser("check", help="load and classify the plan and print a summary")
    check.add_argument("plan_file", type=Path, metavar="PLAN_FILE")
    generate = sub.add_parser("generate", help="write the generated garages (garage13x15, 26x30, 39x45)")
    generate.add_argument("-o", "--output", type=Path, help="folder to write them into (default: the project's plans/)")
    return parser


COMMAND = shell.Command("garage_exp.plan")


def run(args: argparse.Namespace) -> int:
    if args.command == "generate":
        from garage_exp.plan.generate import write_plans

        for path in write_plans(*([args.output] if args.output else [])):
            print(path)
        return 0
    classified = classify(load_plan(args.plan_file))
    if args.command == "map":
        from garage_exp.plan.draw import draw_map  # matplotlib only when drawing

        out = args.output or Path(f"{args.plan_file.stem}_map.png")
        print(draw_map(classified, out))
    else:
        print(summary(classified))
    return 0


def main(argv: list[str] | None = None) -> int:
    """The command in the one shell (garage_exp.core.shell): bad input one line and 2, Ctrl-C 130, SIGTERM 143."""
    return COMMAND.run_args(_parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
