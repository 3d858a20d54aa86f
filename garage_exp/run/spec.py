"""A job's spec: what the layers below `run` are told about the job, read once from its composed config by the
preflight (run.preflight.preflight puts it on the PreparedJob) and frozen. Results, perception, render and scene
are handed its typed parts (the scoring and fairness rules, the ego, the sensor's and renderer's settings as plain
data, the detector, the outputs, the names), never the DictConfig.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from garage_exp.core.plain import plain
from garage_exp.perception.detect.matching import Scoring
from garage_exp.results.late import EgoConf
from garage_exp.results.table import FairRule, JobNames


@dataclass(frozen=True)
class Outputs:
    """What a job writes beside its frame table."""

    save_frames: str = "key"  # renderer.save_frames: all | key | none
    dataset: bool = False  # the frames with their labels (exports.DatasetExports)
    openscenario: bool = False  # export.openscenario
    trial: int | None = None  # a search trial's number: a lean job (search.trial)

    @property
    def lean(self) -> bool:
        """A search trial: no glTF, plot or key frames (the study's parent holds those), its hardest fair frame."""
        return self.trial is not None


@dataclass(frozen=True)
class JobSpec:
    """One job, as the layers below `run` see it (module doc)."""

    names: JobNames
    scoring: Scoring
    fair: FairRule
    ego: EgoConf
    moving: bool  # the case drives the ego (a late verdict is due)
    sensor: Mapping[str, Any]  # the sensor model's settings (`_target_` and its parameters), plain
    renderer: Mapping[str, Any]  # the renderer's settings, plain
    detector: Any  # garage_exp.perception.detect.Detector, built once by the preflight; None in a dry run
    outputs: Outputs
    seed: int
    replicates: int
    primary: str  # the camera whose frames the summary scores (case.camera, else the rig's first)
    plan_file: str | None = None  # plan.file, for the hint where a case fits

    def renamed(self, names: JobNames) -> "JobSpec":
        """The spec under the names the job logs (run.job.name_levels settles them after the preflight)."""
        return replace(self, names=names)


def job_names(cfg) -> JobNames:
    return JobNames(str(cfg.case.name), str(cfg.light.name), str(cfg.sensor.name), str(cfg.plan.name))


def job_spec(cfg, detector=None) -> JobSpec:
    """The job's spec from its composed (and checked) config; `detector`: the one the preflight built."""
    from garage_exp.scenario.build import moves_ego
    from garage_exp.scene.camera import scored_camera

    return JobSpec(
        names=job_names(cfg), scoring=Scoring.of(cfg.detector), fair=FairRule.of(cfg.search),
        ego=EgoConf(**plain(cfg.ego)), moving=bool(moves_ego(cfg.case)), sensor=plain(cfg.sensor),
        renderer=plain(cfg.renderer), detector=detector,
        outputs=Outputs(str(cfg.renderer.save_frames), bool(cfg.get("dataset")), bool(cfg.export.openscenario),
                        None if cfg.search.trial is None else int(cfg.search.trial)),
        seed=int(cfg.seed), replicates=int(cfg.replicates),
        primary=scored_camera(cfg.camera, str(cfg.case.get("camera") or "")),
        plan_file=None if not cfg.plan.file else str(cfg.plan.file))
