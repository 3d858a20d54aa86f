"""The experiment's config (conf/config.yaml): its schema `Config`, assembled from the nodes each layer registers
beside the code that owns them (core/config_nodes.py: register_node), and the job's own top-level values.

Importing this module imports every owner (their registrations run on import) and assembles `Config` in the
config's order; each command that composes the experiment's config imports it (the main command, gym, the loop).
A new node is its dataclass and one `register_node` line in its owner's module, and that module imported here
when nothing here imports it yet; it comes after the keys ORDER places.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

# The owners: each import registers its nodes (noqa: imported for that).
import garage_exp.openscenario.checks  # noqa: F401 - export
import garage_exp.perception.schema  # noqa: F401 - sensor, detector
import garage_exp.slots.schema  # noqa: F401 - slot_detector
import garage_exp.plan.schema  # noqa: F401 - plan
import garage_exp.render.schema  # noqa: F401 - renderer
import garage_exp.results.late  # noqa: F401 - ego
import garage_exp.scenario.schema  # noqa: F401 - occluder, case, replicate
import garage_exp.scene.schema  # noqa: F401 - garage, light, camera, palette, look, materials, clutter
import garage_exp.search.schema  # noqa: F401 - search, space
import garage_exp.tracking.schema  # noqa: F401 - tracking
from garage_exp.core import schema


@dataclass
class JobValues:
    """The top-level config's own values, which no layer below the job owns."""

    # Extra factors: config groups whose YAML names a scene modifier with `_target_` (see conf/pillar/).
    modifiers: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    replicates: int = 1  # each cell run this many times with seeded nuisance variation (`replicate` node)
    blank: bool = False  # the blank control: only the vehicles, background removed
    dataset: bool = False  # also write frames with YOLO, COCO and KITTI labels (garage_exp/exports)
    resume: bool = False
    dry_run: bool = False  # plan + map + MLflow only: no rendering or detection


# The config's keys in the order it prints them (`--cfg job`) and the schema check meets them: registered nodes
# and JobValues' fields.
ORDER = ("plan", "garage", "light", "camera", "palette", "occluder", "case", "ego", "sensor", "look", "materials",
         "clutter", "detector", "slot_detector", "renderer", "tracking", "space", "modifiers", "seed", "replicates",
         "replicate", "search", "blank", "dataset", "export", "resume", "dry_run")

Config = schema.register_config(schema.assemble(ORDER, JobValues, __name__))
