"""The `plan` group's schema, beside the plan's loading and its generator (plan/generator.py: generator_settings
checks `plan.generator`), registered as a config node here (core/config_nodes.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from garage_exp.core.config_nodes import register_node


@dataclass
class PlanGeneratorConf:
    """`plan=generated`: what the seeded garage generator (garage_exp/plan/generator.py) draws from. A range is
    [lo, hi] (or one value); an integer range includes both ends; `family` is one layout family or a list to draw
    from. Checked by garage_exp.plan.generator.generator_settings; ranges and their sources in docs/plans.md."""

    family: Any = "loop"  # loop | comb | grid | spine, or a list of them
    aisles: Any = field(default_factory=lambda: [2, 3])  # east-west lanes: 3 cells north-south each
    spans: Any = field(default_factory=lambda: [4, 7])  # bay cells along an aisle (pillar to pillar)
    bays_per_span: Any = field(default_factory=lambda: [2, 3])  # bays between two pillars along an aisle
    bay_width: Any = field(default_factory=lambda: [2.3, 2.7])  # m; bays beside a pillar get 2.40 m clear
    bay_depth: Any = field(default_factory=lambda: [5.1, 5.5])  # m (the ordinance: >= 5.0)
    lane_width: Any = field(default_factory=lambda: [5.6, 6.5])  # m; at least the ordinance's for the bay width
    pillar_size: Any = field(default_factory=lambda: [0.4, 0.9])  # m, square section
    ceiling_height: Any = field(default_factory=lambda: [2.5, 3.2])  # m; null: garage.ceiling_height
    ramps: Any = field(default_factory=lambda: [1, 2])  # 1: one two-way ramp; 2: an entrance and an exit
    cores: Any = field(default_factory=lambda: [0, 2])  # stair and lift cores in the islands
    wall_bays: Any = 0.8  # chance that a side of the garage has bays along its wall (else a bare wall)


@dataclass
class PlanConf:
    name: str = "research"
    file: Optional[str] = None  # any plan file; overrides `name` (shipped plans live in plans/NAME.yaml)
    seed: Optional[int] = None  # plan=generated: which draw of the generator
    generator: Optional[PlanGeneratorConf] = None  # plan=generated: the generator's ranges (conf/plan/generated.yaml)


register_node("plan", PlanConf, group=True)
