"""An exported gym scenario's `defaults:` keep the groups' order they had before config nodes moved beside their
owners (issue 48: every exported byte unchanged)."""

import yaml

from conftest import compose_cfg
from garage_exp.gym import export


def test_the_exported_defaults_keep_their_order(monkeypatch):
    monkeypatch.setattr(export, "scenario_values", lambda job, record, movers: {})
    record = {"values": {}, "late": False, "critical_distance": 5.0, "detection_distance": None, "difficulty": 0.5,
              "fair_frames": 1, "ego": [0.0]}
    text = export.scenario_yaml(compose_cfg(), "s", record, [])
    groups = [next(iter(d))[len("override /"):] for d in yaml.safe_load(text)["defaults"] if isinstance(d, dict)]
    assert groups == [g for g in export.EXPORTED_ORDER if g in groups]
    assert groups.index("sensor") + 1 == groups.index("detector")  # the bytes of files exported before the move
