"""A job's spec: what the layers below `run` are told about the job, read once from its composed config by the
preflight (run.preflight.preflight puts it on the PreparedJob) and frozen. Results, perception, render and scene
are handed its typed parts (the scoring and fairness rules, the ego, the sensor's and renderer's settings as plain
data, the detector, the outputs, the names, the frame pipeline's FrameConf, the scene builder's SceneSpec), never
the config (the job keeps the converted config on the PreparedJob: what tracking logs and hashes)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from garage_exp.core.plain import Settings, plain, settings, typed
from garage_exp.perception.detect.matching import Scoring
from garage_exp.results.late import EgoConf
from garage_exp.results.table import FairRule, JobNames
from garage_exp.scenario.schema import CaseConf, OccluderConf, ReplicateConf
from garage_exp.scenario.spec import SceneSpec
from garage_exp.scene.schema import (CameraRigConf, ClutterConf, GarageConf, LightConf, LookConf, MaterialsConf,
                                     PaletteConf)


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
class FrameConf:
    """What the frame pipeline (run.pipeline.FramePipeline) reads of the job's settings, read once: not the
    config."""

    look: str  # look.name: the flat look keeps its published order of the blank control's compositing
    materials: MaterialsConf  # the materials group: each replicate's own draw (scene.look.dress_for)
    seed: int
    wear: float  # the line paint's wear (scenario.assemble.marking_wear): a replicate's draw wears with it
    dataset: bool  # the frames are labelled in 3D (each frame's geometry is kept)

    @classmethod
    def of(cls, job: SceneSpec, dataset: bool) -> "FrameConf":
        """From the scene builder's settings (the look, materials, seed and wear it dressed the scene with)."""
        from garage_exp.scenario.assemble import marking_wear

        return cls(str(job.look.name), job.materials, int(job.seed), marking_wear(job), dataset)

    @classmethod
    def of_config(cls, cfg) -> "FrameConf":
        """From a config (a node or its Settings): tests and benchmarks that build a pipeline without a job."""
        cfg = settings(cfg)
        return cls.of(scene_spec(cfg), bool(cfg.get("dataset")))


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
    scene: SceneSpec | None = None  # what the scene builder is told (scene_spec)
    frames: FrameConf | None = None  # what the frame pipeline is told
    slot_detector: Settings | None = None  # the slot_detector group, plain (slots/frames.py's finder)
    plan_file: str | None = None  # plan.file, for the hint where a case fits


def job_names(cfg) -> JobNames:
    return JobNames(str(cfg.case.name), str(cfg.light.name), str(cfg.sensor.name), str(cfg.plan.name))


def config_sources() -> tuple[tuple[str, ...], dict[str, Any]]:
    """The command's config folders and group choices (Hydra's runtime), read here, at the job, so that the scene
    builder is handed them (scenario/build.py's level_file names the file a bad value came from); none outside a
    Hydra app (tests, the sweep's preflight)."""
    from hydra.core.hydra_config import HydraConfig

    try:
        runtime = HydraConfig.get().runtime
    except ValueError:
        return (), {}
    return tuple(s.path for s in runtime.config_sources if s.schema == "file"), dict(runtime.choices)


def scene_spec(cfg) -> SceneSpec:
    """The scene builder's settings from the job's composed config (a job's, a search trial's, the adversary's):
    each group as its schema's dataclass, converted here once (a config without a group: its defaults)."""
    cfg = settings(cfg)
    part = lambda schema, key: typed(schema, cfg.get(key) or {}, key)  # noqa: E731
    dirs, choices = config_sources()
    return SceneSpec(garage=part(GarageConf, "garage"), light=part(LightConf, "light"),
                     palette=part(PaletteConf, "palette"), camera=part(CameraRigConf, "camera"),
                     case=part(CaseConf, "case"), occluder=part(OccluderConf, "occluder"),
                     replicate=part(ReplicateConf, "replicate"), look=part(LookConf, "look"),
                     materials=part(MaterialsConf, "materials"), clutter=part(ClutterConf, "clutter"),
                     modifiers=cfg.get("modifiers") or Settings(), ego_speed=float(part(EgoConf, "ego").speed),
                     seed=int(cfg.get("seed") or 0), replicates=int(cfg.get("replicates", 1)),
                     blank=bool(cfg.get("blank")), config_dirs=dirs, choices=choices)


def job_spec(config, detector=None, scene: SceneSpec | None = None) -> JobSpec:
    """The job's spec from its composed (and checked) config, as plain data (the preflight's one conversion; a
    node given is converted here); `detector`: the one the preflight built; `scene`: its scene_spec, if built."""
    from garage_exp.scenario.build import moves_ego
    from garage_exp.scene.camera import scored_camera

    config = settings(config)
    scene = scene or scene_spec(config)
    search = config.search
    outputs = Outputs(str(config.renderer.save_frames), bool(config.get("dataset")), bool(config.export.openscenario),
                      None if search.get("trial") is None else int(search.trial))
    return JobSpec(
        names=job_names(config), scoring=Scoring.of(config.detector), fair=FairRule.of(search),
        ego=EgoConf(**plain(config.ego)), moving=bool(moves_ego(scene.case)), sensor=plain(config.sensor),
        renderer=plain(config.renderer), detector=detector, outputs=outputs,
        seed=int(config.seed), replicates=int(config.replicates),
        primary=scored_camera(scene.camera, str(scene.case.camera or "")), scene=scene,
        frames=FrameConf.of(scene, outputs.dataset), slot_detector=config.get("slot_detector"),
        plan_file=None if not config.plan.get("file") else str(config.plan.file))
