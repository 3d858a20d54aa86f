"""The `tracking` group's schema (the MLflow store and experiment a command logs to), beside the tracking client,
registered as a config node here (core/config_nodes.py); the other commands' configs embed it with their own
experiment (gym, train, loop, verify).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from garage_exp.core.config_nodes import register_node


@dataclass
class TrackingConf:
    name: str = "mlflow"
    uri: Optional[str] = None  # None: $MLFLOW_TRACKING_URI, else sqlite:///<project>/outputs/mlflow.db
    experiment: str = "garage_exp"


register_node("tracking", TrackingConf, group=True)
