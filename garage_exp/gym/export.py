"""A trained adversary's episodes as scenario files and as a graded suite, in the search's format
(garage_exp/search/suite.py): each scenario is a standalone YAML (`<suite>/scenario/<band>_<k>.yaml`: the
episode's group levels and every resolved value) that a job reruns,

    python -m garage_exp --config-dir <suite> +scenario=hard_1

with a manifest (manifest.csv) and an index (README.md); with `export.openscenario=true`, each scenario as
OpenSCENARIO and OpenDRIVE too (openscenario/<scenario>/scenario.xosc, garage.xodr). Bands are the search's (confidence over the fair
frames), over the episodes whose target was fairly visible before the critical distance.

An episode fixes the ego's drive (its rendered frames' motion values, `case.motion.values`) and the adversary's
values: a value moved each step as the case's co-motion's per-frame values (`case.motion.along.<actor>.values`),
a `once` value (a person's offset in its gap) as the actor's own. A job places them as the environment did (the
same `resolve`, scenario/live.py) and holds them to the same rule of what may stand (the environment's bounds
are that rule's, gym/limits.py), so the scenario reruns its episode frame for frame.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import yaml
from omegaconf import DictConfig, OmegaConf

from garage_exp.core.config_nodes import group_keys
from garage_exp.results.late import confirmed_text
from garage_exp.search.suite import DEFAULT_BANDS, NOT_SCENARIO, band_of


def scenario_values(job: DictConfig, record: dict, movers) -> dict:
    """The job's resolved values with the case replaced by the episode's."""
    task = OmegaConf.masked_copy(job, [k for k in job if k not in NOT_SCENARIO])
    values = OmegaConf.to_container(task, resolve=True)
    case = values["case"]
    motion = case["motion"]
    motion.update({"start": None, "end": None, "values": [float(v) for v in record["ego"]]})
    along: dict = {}
    for m in movers:
        seq = record["values"][m.name]
        if m.once:  # one value for the whole episode: the actor's own
            case["actors"][m.actor][m.key] = round(float(seq[0]), 6)
        else:
            along[m.actor] = {"key": m.key, "values": [round(float(v), 6) for v in seq]}
    for name, spec in (motion.get("along") or {}).items():
        if name not in along:  # the environment moves only its movers: it held this actor at its own value
            held = float(case["actors"][name][spec["key"]])
            along[name] = {"key": spec["key"], "values": [held] * len(record["ego"])}
    if "along" in motion or along:
        motion["along"] = along
    # One variant: the episode's (its shown actors and target); its `set` values are already the actors' own.
    case["variants"] = [v for k, v in enumerate(case.get("variants") or []) if k == record.get("variant", 0)]
    return values


# The order of an exported file's `defaults:` (the groups' order before config nodes moved beside their owners; a
# group registered since goes after them): kept so an export's bytes do not change.
EXPORTED_ORDER = ("plan", "garage", "light", "camera", "palette", "occluder", "case", "sensor", "detector", "look",
                  "materials", "clutter", "slot_detector", "renderer", "space")


def scenario_yaml(job: DictConfig, name: str, record: dict, movers) -> str:
    groups = group_keys()
    order = [g for g in EXPORTED_ORDER if g in groups] + [g for g in groups if g not in EXPORTED_ORDER]
    choices = {g: str(job[g].name) for g in order if g != "tracking" and g in job and "name" in job[g]}
    values = scenario_values(job, record, movers)
    defaults = [{f"override /{group}": level} for group, level in choices.items()] + ["_self_"]
    moves = "; ".join(f"{n}: {', '.join(f'{v:.3f}' for v in seq)}" for n, seq in record["values"].items())
    head = (f"# @package _global_\n# Scenario {name}: an adversary's episode, {'late' if record['late'] else 'in time'}"
            f" (critical distance {record['critical_distance']:.2f} m, {confirmed_text(record['detection_distance'], 2)}"
            f"), difficulty {record['difficulty']:.3f} over "
            f"{record['fair_frames']} fair frame(s).\n"
            f"# Per frame: ego {', '.join(f'{v:g}' for v in record['ego'])}; {moves}\n"
            + "# Rerun: python -m garage_exp --config-dir <this suite's dir> +scenario=" + name + "\n")
    return head + yaml.safe_dump({"defaults": defaults, **values}, sort_keys=False)


def members(records: list[dict], per_band: int, bands: dict) -> dict[str, list[tuple[int, dict]]]:
    """Each band's episodes (testable ones with fair frames), spread over the band as the search's suites are."""
    by_band: dict[str, list[tuple[int, dict]]] = {str(b): [] for b in bands}
    for k, r in enumerate(records):
        if r["testable"] and r["fair_frames"] and not math.isnan(r["difficulty"]):
            band = band_of(1.0 - r["difficulty"], bands)
            if band is not None:
                by_band[band].append((k, r))
    out = {}
    for band, found in by_band.items():
        found.sort(key=lambda kr: (-kr[1]["difficulty"], kr[0]))
        if len(found) > per_band:
            picks = ([round(i * (len(found) - 1) / max(per_band - 1, 1)) for i in range(per_band)]
                     if per_band > 1 else [len(found) // 2])
            found = [found[i] for i in dict.fromkeys(picks)]
        out[band] = found
    return out


def write_suite(job: DictConfig, records: list[dict], root: Path, movers, per_band: int,
                bands: dict | None = None) -> list[Path]:
    """The suite's files under `root`: scenario/<band>_<k>.yaml, manifest.csv and README.md (the index).
    Returns them, the manifest first."""
    bands = bands or DEFAULT_BANDS
    (root / "scenario").mkdir(parents=True, exist_ok=True)
    rows, paths = [], []
    for band, chosen in members(records, per_band, bands).items():
        for k, (index, r) in enumerate(chosen, start=1):
            name = f"{band}_{k}"
            text = scenario_yaml(job, name, r, movers)
            path = root / "scenario" / f"{name}.yaml"
            path.write_text(text)
            paths.append(path)
            if job.export.openscenario:  # the episode as OpenSCENARIO + OpenDRIVE: openscenario/<name>/
                from garage_exp.run.openscenario import export

                values = scenario_values(job, r, movers)
                export(OmegaConf.merge(job, values), root / "openscenario" / name)
            rows.append({"scenario": name, "band": band, "difficulty": round(r["difficulty"], 6),
                         "confidence": round(1.0 - r["difficulty"], 6), "late": r["late"],
                         "detection_distance": r["detection_distance"], "critical_distance":
                         round(r["critical_distance"], 4), "fair_frames": r["fair_frames"], "episode": index,
                         **{f"param.{p}": v for p, v in r["params"].items()}})
    manifest = root / "manifest.csv"
    table = pd.DataFrame(rows)
    table.to_csv(manifest, index=False)
    readme = root / "README.md"
    readme.write_text(index_text(table, len(records), per_band))
    print(f"garage_exp.gym: suite of {len(rows)} scenario(s) in {root} (README.md, manifest.csv)")
    return [manifest, readme, *paths]


def index_text(table: pd.DataFrame, episodes: int, per_band: int) -> str:
    lines = ["# A graded suite from an adversary's episodes", "",
             f"{len(table)} scenario(s) from {episodes} episode(s), up to {per_band} per band (confidence over the "
             "fair frames; the search's bands). Rerun one:", "",
             "    python -m garage_exp --config-dir <this dir> +scenario=NAME", "",
             "| scenario | band | difficulty | late | confirmed at (m) | critical (m) |", "|---|---|---|---|---|---|"]
    for r in table.itertuples():
        lines.append(f"| {r.scenario} | {r.band} | {r.difficulty:.3f} | {'yes' if r.late else 'no'} | "
                     f"{'never' if pd.isna(r.detection_distance) else f'{r.detection_distance:.1f}'} | "
                     f"{r.critical_distance:.1f} |")
    return "\n".join(lines) + "\n"
