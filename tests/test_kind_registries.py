"""Camera views, sensor kinds (and tone curves) and slot detector kinds are registries with the registration beside
what it registers (scene/views.py `@register_view`, perception/sensor.py `@register_sensor_kind`, `@register_tone_curve`,
perception/slots/detector.py `@register_slot_kind`): adding one is one module. Each test adds one from a temporary module
and uses it where the shipped ones are used."""

from __future__ import annotations

import importlib
import sys

import numpy as np
import pytest
import torch
from conftest import compose_cfg, schema_node

from garage_exp.core.errors import GarageError
from garage_exp.perception.sensor import KINDS, TONES, make_sensor
from garage_exp.perception.slots.detector import KINDS as SLOT_KINDS
from garage_exp.scene.views import VIEWS

VIEW_MODULE = '''
from dataclasses import dataclass

from garage_exp.scene.views import Pinhole, register_view


@register_view("narrow")
@dataclass(frozen=True)
class Narrow(Pinhole):
    """A perspective view of the central 60 degrees."""

    @classmethod
    def for_spec(cls, spec):
        return cls.from_fovx(spec.width, spec.height, 60.0)
'''

SENSOR_MODULE = '''
from garage_exp.perception.sensor import register_sensor_kind, register_tone_curve


@register_sensor_kind("negative")
def negative(model, rgb, rng):
    """The frame's negative (numpy or torch alike)."""
    return 255 - rgb


@register_tone_curve("square")
def square(x):
    return x * x
'''

SLOT_MODULE = '''
from garage_exp.perception.slots.detector import SlotKind, register_slot_kind
from garage_exp.perception.slots.marks import SlotFrame


@register_slot_kind("nothing")
class Nothing(SlotKind):
    """Finds no slot, at the image's size."""

    @staticmethod
    def load(conf):
        return lambda image, mpp: SlotFrame([], [], mpp, (image.shape[1], image.shape[0]))
'''


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """Import a module written to a temporary directory; its registrations are removed afterwards."""
    before = {id(r): dict(r) for r in (VIEWS, KINDS, TONES, SLOT_KINDS)}
    monkeypatch.syspath_prepend(str(tmp_path))

    def load(name: str, text: str):
        (tmp_path / f"{name}.py").write_text(text)
        return importlib.import_module(name)

    yield load
    for registry in (VIEWS, KINDS, TONES, SLOT_KINDS):
        registry.clear()
        registry.update(before[id(registry)])
    for name in ("user_view", "user_sensor", "user_slots"):
        sys.modules.pop(name, None)


def test_a_view_from_a_module_of_its_own(plugin):
    from garage_exp.perception.detect import Intrinsics
    from garage_exp.render.fisheye import lens_of, view_lens, view_remap
    from garage_exp.scene.camera import check_camera, rig_specs

    rig = compose_cfg("camera=fisheye", "camera.view=narrow", "camera.width=64", "camera.height=48").camera
    with pytest.raises(GarageError, match="camera.view: unknown view 'narrow'"):
        check_camera(rig)
    plugin("user_view", VIEW_MODULE)
    check_camera(rig)
    (spec,) = rig_specs(rig, (4.77, 1.96, 1.5))[:1]
    view = view_lens(spec)
    assert type(view).__name__ == "Narrow" and abs(view.fx - 32.0 / np.tan(np.radians(30.0))) < 1e-9
    intrinsics = Intrinsics.of(spec)
    assert intrinsics.model == "pinhole" and intrinsics.fx == view.fx  # the detector sees a pinhole view
    map_x, _, flat = view_remap(lens_of(spec), view)
    assert (flat >= 0).all() and map_x.shape == (48, 64)  # 60 degrees lie within the 190-degree lens


def test_a_sensor_kind_and_a_tone_curve_from_a_module_of_their_own(plugin):
    with pytest.raises(GarageError, match="sensor.kind: unknown sensor kind 'negative'"):
        make_sensor(kind="negative")
    plugin("user_sensor", SENSOR_MODULE)
    rgb = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    model = make_sensor(name="neg", kind="negative")
    assert np.array_equal(model.apply(rgb, np.random.default_rng(1)), 255 - rgb)
    assert torch.equal(model.apply_batch(torch.from_numpy(rgb[None])), torch.from_numpy(255 - rgb[None]))
    squared = make_sensor(name="sq", kind="noisy", params={"tone": "square"}).apply(rgb, np.random.default_rng(1))
    plain = make_sensor(name="lin", kind="noisy", params={}).apply(rgb, np.random.default_rng(1))
    assert squared.dtype == np.uint8 and squared.mean() < plain.mean()  # x^2 darkens a signal below full scale


def test_a_slot_detector_kind_from_a_module_of_its_own(plugin):
    from garage_exp.perception.slots.detector import check_slot_detector, load
    from garage_exp.perception.slots.schema import SlotDetectorConf

    conf = schema_node(SlotDetectorConf, {"kind": "nothing"})
    with pytest.raises(GarageError, match="slot_detector.kind: unknown kind 'nothing'"):
        check_slot_detector(conf)
    plugin("user_slots", SLOT_MODULE)
    found = load(conf)(np.zeros((30, 40, 3), np.uint8), 0.05)
    assert found.slots == [] and found.size == (40, 30) and found.meters_per_pixel == 0.05
