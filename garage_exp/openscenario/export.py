"""One export's files: `garage.xodr` (xodr_write.py) and one OpenSCENARIO file per variant (xosc_write.py)."""

from __future__ import annotations

from pathlib import Path

from garage_exp.openscenario.lanes import ego_lane, lane_runs
from garage_exp.openscenario.model import ExportInfo, Track
from garage_exp.openscenario.v1_0 import check_tracks
from garage_exp.openscenario.xodr_write import garage_things, write_xodr
from garage_exp.openscenario.xosc_write import VERSIONS, write_xosc


def write(info: ExportInfo, classified, variants: list[tuple[str, str, float | None, list[Track], list[str]]],
          out: Path) -> list[Path]:
    """`out`/garage.xodr and one .xosc per variant (label, its target, its frames' step, its actors' tracks,
    notes): `scenario.xosc`, `scenario_2.xosc`, ...; the paths."""
    version = info.version
    for label, _, _, moving, _ in variants:
        check_tracks(version, label, moving)
    runs = lane_runs(classified)
    lanes = [ego_lane(runs, next(t for t in moving if t.name == "ego")) for _, _, _, moving, _ in variants]
    # one garage, one rule: the side the ego keeps to (a case's variants drive the same side)
    rule = next((lane.rule for lane in lanes if lane is not None), "RHT")
    lanes = [lane if lane is None or lane.rule == rule else None for lane in lanes]
    xodr_path = write_xodr(classified, out / "garage.xodr", rule, garage_things(
        classified, info.pillar_size, info.ceiling_height, info.wall_thickness))
    paths = [xodr_path]
    for k, ((label, target, step, moving, notes), lane) in enumerate(zip(variants, lanes), start=1):
        name = "scenario.xosc" if k == 1 else f"scenario_{k}.xosc"
        paths.append(write_xosc(info, moving, label, notes, out / name, xodr_path.name, target, step, lane,
                                runs, VERSIONS[version]))
    return paths
