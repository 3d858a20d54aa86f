"""core.plugins.build: the project's own code named by plain settings is called directly, as
`hydra.utils.instantiate(settings, *args, _convert_="all", **kwargs)` calls it (a draw of the wide space builds a
dozen components; instantiate's copy, merge and checks cost ~2 ms each). Each shipped sensor and detector level and
a scene modifier is built alike both ways; a target's refusals read the same; what instantiate would treat
otherwise (its own keys, `${...}`, a caller's dict, a user's module) still goes through it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import compose_cfg

from garage_exp.core import plugins
from garage_exp.core.errors import GarageError
from garage_exp.core.plain import plain


def through_hydra(monkeypatch, node, what, where, *args, **kwargs):
    with monkeypatch.context() as patch:
        patch.setattr(plugins, "direct", lambda settings, kwargs: False)
        return plugins.build(node, what, where, *args, **kwargs)


def same(a, b) -> bool:
    """Equal components: the same type and fields (arrays by value)."""
    if type(a) is not type(b):
        return False
    if dataclasses.is_dataclass(a):
        a, b = dataclasses.asdict(a), dataclasses.asdict(b)
    elif hasattr(a, "__dict__"):
        a, b = vars(a), vars(b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b)
    return a == b


@pytest.mark.parametrize("level", ["ideal", "camera", "noisy", "lowlight"])
def test_a_sensor_is_built_as_instantiate_builds_it(monkeypatch, level):
    node = compose_cfg(f"sensor={level}").sensor
    assert plugins.direct(plain(node), {})  # the direct call is the one tested
    assert same(plugins.build(node, "a sensor", "sensor"), through_hydra(monkeypatch, node, "a sensor", "sensor"))


@pytest.mark.parametrize("overrides", [(), ("detector.models=[yolo11n_int8_openvino_model,yolov8n_int8_openvino_model]",
                                            "detector.conf=0.1")])
def test_the_detectors_settings_are_built_as_instantiate_builds_them(monkeypatch, overrides):
    node = compose_cfg(*overrides).detector
    assert plugins.direct(plain(node), {})
    assert same(plugins.build(node, "a detector", "detector"), through_hydra(monkeypatch, node, "a detector",
                                                                            "detector"))


def test_a_modifier_gets_the_callers_arguments_first(monkeypatch):
    calls = []

    def modifier(scene, classified, garage, size: float = 0.6):
        calls.append((scene, classified, garage, size, type(size)))

    import garage_exp.scene.modifiers as modifiers

    monkeypatch.setattr(modifiers, "probe_modifier", modifier, raising=False)
    node = {"_target_": "garage_exp.scene.modifiers.probe_modifier", "size": 1}
    scene, classified = object(), object()
    plugins.build(node, "a modifier", "modifiers.probe", scene, classified, "garage")
    through_hydra(monkeypatch, node, "a modifier", "modifiers.probe", scene, classified, "garage")
    assert calls[0] == calls[1] and calls[0][0] is scene and calls[0][3:] == (1, int)


def test_a_targets_refusals_read_the_same(monkeypatch):
    import garage_exp.scene.modifiers as modifiers

    def boom(scene, size: float = 0.6):
        raise ValueError(f"size {size} is no good")

    monkeypatch.setattr(modifiers, "probe_boom", boom, raising=False)
    node = {"_target_": "garage_exp.scene.modifiers.probe_boom", "size": 2.0}
    errors = []
    for build in (plugins.build, lambda *a: through_hydra(monkeypatch, *a)):
        with pytest.raises(Exception) as raised:
            build(node, "a modifier", "modifiers.boom", "scene")
        errors.append((type(raised.value), str(raised.value)))
        with pytest.raises(GarageError) as wrong:  # a setting the target does not take: one line naming the place
            build({**node, "sise": 1.0}, "a modifier", "modifiers.boom", "scene")
        errors.append((wrong.value.where, str(wrong.value)))
        with pytest.raises(GarageError) as refused:  # the target's own GarageError, as it is
            build({"_target_": "garage_exp.perception.sensor.make_sensor", "kind": "noisy",
                   "params": {"gain": 2.0}}, "a sensor", "sensor")
        errors.append((refused.value.where, str(refused.value)))
    assert errors[:3] == errors[3:]
    assert "size 2.0 is no good" in errors[0][1] and "sise" in errors[1][1] and errors[2][0] == "sensor.params"


@pytest.mark.parametrize("settings, kwargs", [
    ({"_target_": "garage_exp.x.f", "inner": {"_target_": "garage_exp.x.g"}}, {}),  # nested: instantiate builds it
    ({"_target_": "garage_exp.x.f", "_partial_": True}, {}),
    ({"_target_": "garage_exp.x.f", "text": "${oc.env:HOME}"}, {}),  # instantiate resolves it
    ({"_target_": "garage_exp.x.f", "size": "???"}, {}),  # instantiate refuses it as missing
    ({"_target_": "garage_exp.x.f", "items": [{"_args_": [1]}]}, {}),
    ({"_target_": "garage_exp.x.f", "when": np.datetime64("2026-01-01")}, {}),  # not plain data
    ({"_target_": "garage_exp.x.f"}, {"options": {"a": 1}}),  # a caller's dict: instantiate hands a copy
])
def test_what_instantiate_treats_otherwise_goes_through_it(settings, kwargs):
    assert not plugins.direct(settings, kwargs)
    assert plugins.direct({"_target_": "garage_exp.x.f", "a": [1, 2.5, None, "t", {"b": (True,)}]}, {"scene": object()})


def test_a_users_module_goes_through_instantiate(monkeypatch, tmp_path):
    (tmp_path / "my_mods.py").write_text("def widen(scene, by=1.0):\n    return ('widened', scene, by)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("GARAGE_EXP_MODIFIER_MODULES", "my_mods")
    called = []
    import hydra.utils

    real = hydra.utils.instantiate
    monkeypatch.setattr(hydra.utils, "instantiate", lambda *a, **k: called.append(a) or real(*a, **k))
    assert plugins.build({"_target_": "my_mods.widen", "by": 2}, "a modifier", "modifiers.w", "s") == ("widened", "s", 2)
    assert len(called) == 1
