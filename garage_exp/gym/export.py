"""A trained adversary's episodes as scenario files and as a graded suite, in the search's format
(garage_exp/search/suite.py): each scenario is a standalone YAML (`<suite>/scenario/<band>_<k>.yaml`: the
episode's group levels and every resolved value) that a job reruns,

    python -m garage_exp --config-dir <suite> +scenario=hard_1

with a manifest (manifest.csv) and an index (README.md); with `export.openscenario=true`, each scenario as
OpenSCENARIO and OpenDRIVE too (openscenario/<scenario>/scenario.xosc, garage.xodr). Bands are the search's (confidence over the fair
frames), over the episodes whose target was fairly visible before the critical distance.

An episode fixes the ego's drive (its rendered frames' motion values) and the adversary's values per frame. The
case's co-motion (`case.motion.along`) takes a person's per-frame `values` where the schema has them (exact);
otherwise it gets the nearest walk it can express - still until `at`, then `speed` up to `end` - and the
scenario says so (`exact: false` in the manifest, the values in the file's header).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pandas as pd
import yaml
from omegaconf import DictConfig, OmegaConf

from garage_exp.core.schema import GROUPS
from garage_exp.results.late import confirmed_text
from garage_exp.search.suite import DEFAULT_BANDS, NOT_SCENARIO, band_of


def along_takes_values() -> bool:
    from garage_exp.core import schema

    along = getattr(schema, "AlongConf", None)
    return along is not None and "values" in {f.name for f in dataclasses.fields(along)}


def fitted_walk(values: list[float], ego: list[float], start: float, speed_ms: float) -> dict:
    """The co-motion nearest an episode's values (frame by frame, with the ego's motion values `ego`): still at
    `start` until the ego is `at`, then the mean speed from leaving the start to first reaching the farthest value
    (m/s of the ego's time), up to that value."""
    prev = [start, *values]
    moving = [i for i in range(len(values)) if abs(prev[i + 1] - prev[i]) > 1e-6]
    top = max(values) if values else start
    if not moving or top <= start:
        return {"start": start, "end": start, "speed": 0.0, "at": None}
    first = moving[0]
    last = values.index(top)
    frame_s = abs(ego[1] - ego[0]) / speed_ms if len(ego) > 1 else 1.0
    return {"start": start, "end": round(top, 4), "at": ego[first - 1] if first > 0 else None,
            "speed": round((top - start) / ((last - first + 1) * frame_s), 4)}


def scenario_values(job: DictConfig, record: dict, movers, speed_ms: float, slides: bool = False
                    ) -> tuple[dict, bool]:
    """The job's resolved values with the case replaced by the episode's: (values, exact)."""
    task = OmegaConf.masked_copy(job, [k for k in job if k not in NOT_SCENARIO])
    values = OmegaConf.to_container(task, resolve=True)
    case = values["case"]
    motion = case["motion"]
    motion.update({"start": None, "end": None, "values": [float(v) for v in record["ego"]]})
    exact = True
    along: dict = {}
    for m in movers:
        seq = record["values"][m.name]
        if m.once:  # one value for the whole episode: the actor's own
            case["actors"][m.actor][m.key] = round(float(seq[0]), 6)
            # a person's offset in a gap: build.py's placement does not take it yet (scenario/live.py slides it)
            exact = exact and not (slides and m.key == "offset" and case["actors"][m.actor].get("between"))
            continue
        if along_takes_values():
            along[m.actor] = {"key": m.key, "values": [round(float(v), 6) for v in seq]}
            continue
        exact = False
        walk = fitted_walk(seq, record["ego"], m.start, speed_ms)
        along[m.actor] = {"key": m.key, **walk}
    if "along" in motion or along:
        motion["along"] = along
    # One variant: the episode's (its shown actors and target); its `set` values are already the actors' own.
    case["variants"] = [v for k, v in enumerate(case.get("variants") or []) if k == record.get("variant", 0)]
    return values, exact


def scenario_yaml(job: DictConfig, name: str, record: dict, movers, speed_ms: float, slides: bool = False
                  ) -> tuple[str, bool]:
    choices = {g: str(job[g].name) for g in GROUPS if g != "tracking" and g in job and "name" in job[g]}
    values, exact = scenario_values(job, record, movers, speed_ms, slides)
    defaults = [{f"override /{group}": level} for group, level in choices.items()] + ["_self_"]
    moves = "; ".join(f"{n}: {', '.join(f'{v:.3f}' for v in seq)}" for n, seq in record["values"].items())
    head = (f"# @package _global_\n# Scenario {name}: an adversary's episode, {'late' if record['late'] else 'in time'}"
            f" (critical distance {record['critical_distance']:.2f} m, {confirmed_text(record['detection_distance'], 2)}"
            f"), difficulty {record['difficulty']:.3f} over "
            f"{record['fair_frames']} fair frame(s).\n"
            f"# Per frame: ego {', '.join(f'{v:g}' for v in record['ego'])}; {moves}\n"
            + ("" if exact else "# Not exact: the co-motion below is the nearest constant-speed walk to those "
                                "values (the schema has no per-frame values for it), and a person's offset in a "
                                "gap is not placed by a job yet: a rerun approximates the episode.\n")
            + "# Rerun: python -m garage_exp --config-dir <this suite's dir> +scenario=" + name + "\n")
    return head + yaml.safe_dump({"defaults": defaults, **values}, sort_keys=False), exact


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


def write_suite(job: DictConfig, records: list[dict], root: Path, movers, speed_ms: float, per_band: int,
                bands: dict | None = None, slides: bool = False) -> list[Path]:
    """The suite's files under `root`: scenario/<band>_<k>.yaml, manifest.csv and README.md (the index).
    Returns them, the manifest first. `slides`: the env slid a person along its gap itself (LiveScenario)."""
    bands = bands or DEFAULT_BANDS
    (root / "scenario").mkdir(parents=True, exist_ok=True)
    rows, paths = [], []
    for band, chosen in members(records, per_band, bands).items():
        for k, (index, r) in enumerate(chosen, start=1):
            name = f"{band}_{k}"
            text, exact = scenario_yaml(job, name, r, movers, speed_ms, slides)
            path = root / "scenario" / f"{name}.yaml"
            path.write_text(text)
            paths.append(path)
            if job.export.openscenario:  # the episode as OpenSCENARIO + OpenDRIVE: openscenario/<name>/
                from garage_exp.run.openscenario import export

                values, _ = scenario_values(job, r, movers, speed_ms, slides)
                export(OmegaConf.merge(job, values), root / "openscenario" / name)
            rows.append({"scenario": name, "band": band, "difficulty": round(r["difficulty"], 6),
                         "confidence": round(1.0 - r["difficulty"], 6), "late": r["late"],
                         "detection_distance": r["detection_distance"], "critical_distance":
                         round(r["critical_distance"], 4), "fair_frames": r["fair_frames"], "episode": index,
                         "exact": exact, **{f"param.{p}": v for p, v in r["params"].items()}})
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
             "| scenario | band | difficulty | late | confirmed at (m) | critical (m) | exact |", "|---|---|---|---|---|---|---|"]
    for r in table.itertuples():
        lines.append(f"| {r.scenario} | {r.band} | {r.difficulty:.3f} | {'yes' if r.late else 'no'} | "
                     f"{'never' if pd.isna(r.detection_distance) else f'{r.detection_distance:.1f}'} | "
                     f"{r.critical_distance:.1f} | {'yes' if r.exact else 'no'} |")
    return "\n".join(lines) + "\n"
