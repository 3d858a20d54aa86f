"""`python -m garage_exp.plan map PLAN_FILE [-o out.png]` draws a plan; `... check PLAN_FILE` summarises it;
`... generate [-o DIR]` writes the generated big garages (plan/generate.py) into plans/; `... draw --seed N
[KEY=VALUE ...] [-o F.yaml] [--map F.png]` saves a draw of the garage generator (plan=generated,
plan/generator.py) as a plan file that `plan.file=F.yaml` reuses.
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
        *([f"garage: {', '.join(f'{k} {v:g} m' for k, v in plan.garage)} (a generated plan's, set by its jobs)"]
          if plan.garage else []),
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
    sample = sub.add_parser("draw", help="save a draw of the garage generator (plan=generated) as a plan file")
    sample.add_argument("--seed", type=int, default=0, help="plan.seed: which draw (default 0)")
    sample.add_argument("--settings", type=Path, metavar="FILE",
                        help="a YAML mapping of generator settings (plan.generator's keys); default conf/plan/generated.yaml's")
    sample.add_argument("settings_given", nargs="*", metavar="KEY=VALUE",
                        help="generator settings over those, as in plan.generator.KEY=VALUE: family=comb aisles=[2,4]")
    sample.add_argument("-o", "--output", type=Path, help="plan YAML to write (default: the YAML on stdout)")
    sample.add_argument("--map", type=Path, metavar="PNG", help="also draw the plan's map there")
    return parser


def generator_node(args: argparse.Namespace) -> dict:
    """The generator settings of a `draw`: conf/plan/generated.yaml's (or --settings FILE's), then KEY=VALUE."""
    import yaml

    from garage_exp.core.errors import GarageError
    from garage_exp.core.paths import PROJECT_ROOT

    source = args.settings or PROJECT_ROOT / "conf" / "plan" / "generated.yaml"
    try:
        data = yaml.safe_load(source.read_text()) if source.is_file() else None
    except (yaml.YAMLError, OSError, UnicodeDecodeError) as exc:
        raise GarageError(f"not a YAML mapping of generator settings ({type(exc).__name__})", str(source)) from None
    if args.settings and not source.is_file():
        raise GarageError("settings file not found", str(source))
    if isinstance(data, dict) and not args.settings:
        data = data.get("generator")  # the plan group's level: its generator node
    elif isinstance(data, dict) and "generator" in data and isinstance(data["generator"], dict):
        data = data["generator"]  # a copy of conf/plan/generated.yaml
    if not isinstance(data, dict):
        raise GarageError("expected a mapping of generator settings (plan.generator's keys)", str(source))
    node = dict(data)
    for item in args.settings_given:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise GarageError(f"{item!r} is not KEY=VALUE", "draw")
        try:
            node[key.removeprefix("plan.generator.")] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise GarageError(f"{value!r} is not a YAML value", f"plan.generator.{key}") from None
    return node


def draw_command(args: argparse.Namespace) -> int:
    from garage_exp.core.errors import GarageError
    from garage_exp.plan.generator import check_seed, draw, draw_yaml, generator_settings

    node = generator_node(args)
    try:
        d = draw(generator_settings(node), check_seed(args.seed))
    except GarageError as exc:  # name the settings file beside the key it came from
        if args.settings and exc.where and exc.where.startswith("plan.generator."):
            raise exc.again(str(exc).split(": ", 1)[1], f"{args.settings}: {exc.where}") from None
        raise
    text = draw_yaml(d)
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(text)
        print(args.output)
    else:
        sys.stdout.write(text)
    if args.map:
        from garage_exp.plan.draw import draw_map

        print(draw_map(classify(d.plan), args.map, pillar_size=d.garage["pillar_size"]))
    return 0


COMMAND = shell.Command("garage_exp.plan")


def run(args: argparse.Namespace) -> int:
    if args.command == "draw":
        return draw_command(args)
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
