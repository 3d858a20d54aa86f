"""What the scene builder is told about a job: each config group it reads as the typed dataclass that owns it
(scene/schema.py, scenario/schema.py: the registered nodes), converted once by `run.spec.scene_spec` from the
composed config (core.plain.typed), never the job's config node. A misspelt key is an AttributeError at the line
that reads it, not a dict's silent None; the scenario's builders (assemble, build, actors, arrange, replicate,
live) read it by attribute (`job.garage.ceiling_height`, `job.case.motion.step`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from garage_exp.scenario.schema import CaseConf, OccluderConf, ReplicateConf
from garage_exp.scene.schema import (CameraRigConf, ClutterConf, GarageConf, LightConf, LookConf, MaterialsConf,
                                     PaletteConf)


@dataclass(frozen=True)
class SceneSpec:
    garage: GarageConf
    light: LightConf
    palette: PaletteConf
    camera: CameraRigConf
    case: CaseConf
    occluder: OccluderConf
    replicate: ReplicateConf  # the replicates' jitter ranges
    look: LookConf
    materials: MaterialsConf
    clutter: ClutterConf
    # the extra factors: group -> its scene modifier's spec (`_target_` and its keyword arguments, as each modifier
    # declares them: scene/modifiers.py), plain read-only data
    modifiers: Mapping[str, Any]
    ego_speed: float  # km/h (ego.speed): the time of a frame when the case drives the ego
    seed: int
    replicates: int = 1
    blank: bool = False
    # where the command's config came from (Hydra's file sources and group choices, read by the job: run/spec.py),
    # for errors that name the YAML file a value came from (build.level_file); none outside a Hydra app
    config_dirs: tuple[str, ...] = ()
    choices: Mapping[str, Any] = field(default_factory=dict)
