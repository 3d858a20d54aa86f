"""Graded suites (`search.mode=suite`): K fairly visible scenarios per difficulty band, kept as files.

Each scenario is a standalone YAML (`<suite>/scenario/<band>_<k>.yaml`: the trial's group levels and every
resolved value) that reruns to the trial's frame table:

    python -m garage_exp --config-dir <suite> +scenario=hard_1

with a manifest (manifest.csv: band, the objective's value (difficulty, lateness, ...), visible fraction, overrides) and, with `dataset=true`, the
suite's frames as a dataset: each scenario is rerun with dataset=true into dataset/<scenario>/ (YOLO, COCO,
KITTI), with one YOLO data.yaml and one COCO file over all of them; with `export.openscenario=true`, each
scenario as OpenSCENARIO and OpenDRIVE too (openscenario/<scenario>/scenario.xosc, garage.xodr).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import yaml
from omegaconf import DictConfig, OmegaConf
from optuna.trial import TrialState

from garage_exp.core.errors import GarageError
from garage_exp.core.paths import OUTPUTS_DIR
from garage_exp.results.summary import JobSummary
from garage_exp.search.objectives import objective

# Keys a scenario file leaves out: how and where a run is tracked is the rerunning user's, not the scenario's.
NOT_SCENARIO = ("hydra", "tracking", "search", "resume", "dry_run", "dataset", "export")


LEVEL = "level_"  # a graded suite's bands: level_1 (the easiest) .. level_N (search/grade.py measures them)
DEFAULT_BANDS = {"easy": [0.7, 1.01], "moderate": [0.4, 0.7], "hard": [0.0, 0.4]}


def level_bands(n: int) -> dict[str, list[float]]:
    """N levels of equal width on the composite confidence, level 1 the easiest ([1 - 1/N, 1.01): a confidence of
    exactly 1 belongs to it) to level N the hardest ([0, 1/N))."""
    if n < 2:
        raise GarageError(f"{n} levels: a graded suite has at least 2", "search.suite.levels")
    edges = [1.0 - k / n for k in range(n + 1)]
    return {f"{LEVEL}{k + 1}": [round(edges[k + 1], 9), 1.01 if k == 0 else round(edges[k], 9)] for k in range(n)}


def bands_of(search) -> dict:
    """The suite's bands: its own, else its `levels` (search/grade.py), else easy, moderate and hard."""
    if search.suite.bands:
        return dict(search.suite.bands)
    if int(search.suite.get("levels") or 0):
        return level_bands(int(search.suite.levels))
    return DEFAULT_BANDS


def band_of(confidence: float, bands) -> str | None:
    for name, (low, high) in bands.items():
        if float(low) <= confidence < float(high):
            return str(name)
    return None


def members(study, search) -> dict[str, list]:
    """Each band's scenarios: its complete (so fairly visible) trials spread over the band - sorted by
    confidence and taken at evenly spaced ranks, so a band's K scenarios are not K copies of its easiest one."""
    bands = bands_of(search)
    by_band: dict[str, list] = {str(name): [] for name in bands}
    for trial in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        band = band_of(1.0 - trial.values[0], bands)
        if band is not None:
            by_band[band].append(trial)
    k = int(search.suite.per_band)
    out = {}
    for band, trials in by_band.items():
        if search.sampler == "archive":  # the archive's suite: one scenario per cell of a band, many failure kinds
            from garage_exp.search.archive import spread_over_cells

            trials = spread_over_cells(trials, search)
        trials.sort(key=lambda t: (t.values[0], t.number))
        if len(trials) > k:
            picks = [round(i * (len(trials) - 1) / max(k - 1, 1)) for i in range(k)] if k > 1 else [len(trials) // 2]
            trials = [trials[i] for i in dict.fromkeys(picks)]
        out[band] = trials
    return out


def bands_full(study, search) -> bool:
    return all(len(v) >= int(search.suite.per_band) for v in members(study, search).values())


def suite_dir(config: DictConfig, study_name: str) -> Path:
    return Path(config.search.suite.dir) if config.search.suite.dir else OUTPUTS_DIR / "suites" / study_name


def scenario_yaml(job: DictConfig, name: str, trial) -> str:
    """A trial's composed config as a scenario file: its group levels as defaults overrides, then every value
    (resolved), so that it reruns to the same frames even when a level's file changes later."""
    choices = {g: c for g, c in job.hydra.runtime.choices.items() if "/" not in g and g != "hydra" and c is not None
               and not g.endswith("_schema")}
    task = OmegaConf.masked_copy(job, [k for k in job if k not in NOT_SCENARIO])  # Hydra's node is not resolvable here
    values = OmegaConf.to_container(task, resolve=True)
    defaults = [{f"override /{group}": str(level)} for group, level in choices.items()] + ["_self_"]
    metric = objective(str(job.search.objective)).metric
    head = (f"# @package _global_\n# Scenario {name}: trial {trial.number}, {metric} {trial.values[0]:.3f} over "
            f"{trial.user_attrs.get('fair_frames')} fair frame(s), visible fraction "
            f"{trial.user_attrs.get('visible_fraction', 0):.2f}.\n# Rerun: python -m garage_exp --config-dir <this "
            f"suite's dir> +scenario={name}\n")
    return head + yaml.safe_dump({"defaults": defaults, **values}, sort_keys=False)


def write_suite(config: DictConfig, study, loader, launch=None, name: str = "") -> list[Path]:
    """The suite's files: scenario YAMLs, manifest.csv and, with dataset=true and a launcher, the dataset.
    Returns the manifest and scenario files (to log on the study's parent run)."""
    root = suite_dir(config, name or study.study_name)
    (root / "scenario").mkdir(parents=True, exist_ok=True)
    rows, paths, reruns = [], [], []
    goal = objective(str(config.search.objective))
    metric = goal.metric  # the manifest's value column: difficulty, lateness, ...
    chosen = members(study, config.search)
    for band, trials in chosen.items():
        for k, trial in enumerate(trials, start=1):
            scenario = f"{band}_{k}"
            overrides = [o for o in trial.user_attrs["overrides"] if not o.startswith("search.trial=")]
            job = loader.load_sweep_config(config, overrides)
            path = root / "scenario" / f"{scenario}.yaml"
            path.write_text(scenario_yaml(job, scenario, trial))
            paths.append(path)
            if config.export.openscenario:  # the scenario as OpenSCENARIO + OpenDRIVE, beside its YAML
                from garage_exp.run.openscenario import export

                export(job, root / "openscenario" / scenario)
            rows.append({"scenario": scenario, "band": band, metric: round(trial.values[0], 6),
                         "confidence": round(1.0 - trial.values[0], 6) if goal.confidence else None,
                         "visible_fraction": round(trial.user_attrs.get("visible_fraction", 0.0), 6),
                         "fair_frames": trial.user_attrs.get("fair_frames"), "trial": trial.number,
                         "run_id": trial.user_attrs.get("run_id"), "overrides": " ".join(overrides)})
            reruns.append((scenario, [*overrides, f"search.trial={trial.number}"], trial.user_attrs.get("output_dir")))
    if config.export.openscenario and rows:
        paths.append(root / "openscenario")  # a folder: logged as one
    manifest = root / "manifest.csv"
    pd.DataFrame(rows, columns=["scenario", "band", metric, "confidence", "visible_fraction", "fair_frames",
                                "trial", "run_id", "overrides"]).to_csv(manifest, index=False)
    short = {band: len(t) for band, t in chosen.items() if len(t) < int(config.search.suite.per_band)}
    if short:
        print(f"garage_exp: suite {root}: bands short of {config.search.suite.per_band}: "
              + ", ".join(f"{b} {n}" for b, n in short.items()) + " (more trials would fill them)")
    if config.get("dataset") and launch is not None and reruns:
        paths.append(write_dataset(root / "dataset", reruns, launch))
    print(f"garage_exp: suite of {len(rows)} scenario(s) in {root} (manifest.csv)")
    return [manifest, *paths]


def write_dataset(root: Path, reruns: list[tuple[str, list[str], str | None]], launch) -> Path:
    """Rerun each scenario (its trial again, with dataset=true) and gather the datasets: one folder per
    scenario, one YOLO data.yaml listing all their images, one COCO file with every image and annotation
    renumbered. A rerun whose frame table differs from its trial's is reported (it never should)."""
    root.mkdir(parents=True, exist_ok=True)
    batch = [[*overrides, "dataset=true"] for _, overrides, _ in reruns]
    returns = launch(batch, 10_000)
    images, merged = [], {"images": [], "annotations": [], "categories": []}
    for (scenario, _, trial_dir), ret in zip(reruns, returns):
        result = ret.return_value
        if not isinstance(result, JobSummary) or result.output_dir is None:
            print(f"garage_exp: suite scenario {scenario}: its dataset rerun failed: {result}")
            continue
        out = Path(result.output_dir)
        if trial_dir and not pd.read_csv(out / "frames.csv").equals(pd.read_csv(Path(trial_dir) / "frames.csv")):
            print(f"garage_exp: suite scenario {scenario}: the rerun's frames differ from its trial's ({out})")
        source = out / "dataset"
        shutil.copytree(source, root / scenario, dirs_exist_ok=True)
        images.append(f"{scenario}/images")
        coco = json.loads((root / scenario / "coco.json").read_text())
        offset_i, offset_a = len(merged["images"]), len(merged["annotations"])
        remap = {}
        for k, image in enumerate(coco["images"], start=offset_i + 1):
            remap[image["id"]] = k
            merged["images"].append({**image, "id": k, "file_name": f"{scenario}/images/{image['file_name']}"})
        for k, ann in enumerate(coco["annotations"], start=offset_a + 1):
            merged["annotations"].append({**ann, "id": k, "image_id": remap[ann["image_id"]]})
        merged["categories"] = merged["categories"] or coco["categories"]
        merged.setdefault("info", coco.get("info", {}))
    (root / "coco.json").write_text(json.dumps(merged))
    from garage_exp.results.labels import coco_names

    (root / "data.yaml").write_text(yaml.safe_dump({"path": str(root), "train": images, "val": images,
                                                    "names": coco_names()}, sort_keys=False))
    return root
