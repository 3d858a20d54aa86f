"""What the scene builder is told about a job: its config groups as read-only plain data (`core.plain.Settings`),
never the job's config node. `run.spec.scene_spec` builds it from the composed config; the scenario's builders
(assemble, build, actors, arrange, replicate, live) read it by attribute (`job.garage`, `job.get("modifiers")`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from garage_exp.core.plain import Settings


@dataclass(frozen=True)
class SceneSpec:
    garage: Settings
    light: Settings
    palette: Settings
    camera: Settings
    case: Settings
    occluder: Settings
    replicate: Settings  # the replicates' jitter ranges
    look: Settings
    materials: Settings
    clutter: Settings
    modifiers: Mapping[str, Any]
    ego: Settings
    seed: int
    replicates: int = 1
    blank: bool = False
    # where the command's config came from (Hydra's file sources and group choices, read by the job: run/spec.py),
    # for errors that name the YAML file a value came from (build.level_file); none outside a Hydra app
    config_dirs: tuple[str, ...] = ()
    choices: Mapping[str, Any] = field(default_factory=dict)

    def get(self, key: str, default: Any = None) -> Any:
        """A setting by name, `default` when the job has none (as a config node's `get` reads)."""
        return getattr(self, key, default)

    def __getitem__(self, key: str) -> Any:
        return getattr(self, key)
