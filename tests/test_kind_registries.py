"""Every kind a config names by a word is a registry with the registration beside what it registers: camera views
(scene/views.py `@register_view`), sensor kinds and tone curves (perception/sensor.py `@register_sensor_kind`,
`@register_tone_curve`), slot detector kinds (slots/detector.py `@register_slot_kind`), detector entry
kinds (perception/detect/kinds.py `@register_entry_kind`), objectives (search/objectives.py `register_objective`)
and lenses, one per camera model (scene/lenses `@register_lens`): adding one is one module. Each test adds some from a
temporary module and uses them where the shipped ones are used; one adds one of each through $GARAGE_EXP_PLUGINS,
as a user would (docs/architecture.md, "Extension points")."""

from __future__ import annotations

import importlib
import os
import sys

import numpy as np
import pytest
import torch
from conftest import compose_cfg, require, schema_node
from omegaconf import OmegaConf
from optuna.trial import TrialState

from garage_exp.core.errors import GarageError
from garage_exp.perception.detect.kinds import KINDS as ENTRY_KINDS
from garage_exp.perception.sensor import KINDS, TONES, make_sensor
from garage_exp.run.spec import scene_spec
from garage_exp.slots.detector import KINDS as SLOT_KINDS
from garage_exp.scene.lenses import LENSES
from garage_exp.scene.views import VIEWS
from garage_exp.search.objectives import OBJECTIVES

REGISTRIES = (VIEWS, KINDS, TONES, SLOT_KINDS, ENTRY_KINDS, LENSES, OBJECTIVES)
MODULES = ("user_view", "user_sensor", "user_slots", "user_plugin", "user_lens")

VIEW_MODULE = '''
from dataclasses import dataclass

from garage_exp.scene.lenses import Pinhole
from garage_exp.scene.views import register_view


@register_view("narrow")
@dataclass(frozen=True)
class Narrow(Pinhole):
    """A perspective view of the central 60 degrees."""

    @classmethod
    def for_spec(cls, spec):
        return cls.from_fovx(spec.width, spec.height, 60.0)
'''

LENS_MODULE = '''
"""A stereographic lens (r = 2 f tan(theta / 2)), `fov` degrees across the image width: a lens of its own, not
Kannala-Brandt's, written from scratch."""
import math
from dataclasses import dataclass

import numpy as np

from garage_exp.core.errors import check_range
from garage_exp.scene.lenses import NO_K, Lens, register_lens


@register_lens("stereographic")
@dataclass(frozen=True)
class Stereographic(Lens):
    fov: float

    @classmethod
    def check(cls, cam, rig, where):
        check_range(cam.fov, 20.0, 220.0, f"{where}.fov", f"stereographic fov {cam.fov} degrees")

    @classmethod
    def spec_fields(cls, cam, view):
        return {"fov": float(cam.fov), "k": NO_K, "view": view}

    @classmethod
    def of(cls, spec):
        return cls(spec.width, spec.height, spec.fov)

    @property
    def fx(self):
        return self.width / 4.0 / math.tan(math.radians(self.fov) / 4.0)

    @property
    def fy(self):
        return self.fx

    @property
    def cx(self):
        return self.width / 2.0

    @property
    def cy(self):
        return self.height / 2.0

    def rays(self):
        u, v = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        a, b = (u - self.cx) / self.fx, (v - self.cy) / self.fx  # right, down
        r = np.hypot(a, b)
        theta = 2.0 * np.arctan(r / 2.0)
        scale = np.where(r > 1e-12, np.sin(theta) / np.where(r > 1e-12, r, 1.0), 1.0)
        return np.stack([np.cos(theta), -a * scale, -b * scale], axis=-1), theta <= math.radians(self.fov) / 2

    def project(self, d):
        d = np.asarray(d, dtype=float)
        right, down = -d[..., 1], -d[..., 2]
        r = np.hypot(right, down)
        theta = np.arctan2(r, d[..., 0])
        scale = np.where(r > 1e-12, 2.0 * np.tan(theta / 2.0) / np.where(r > 1e-12, r, 1.0), 0.0)
        return self.cx + self.fx * right * scale, self.cy + self.fx * down * scale
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
from garage_exp.slots.detector import SlotKind, register_slot_kind
from garage_exp.slots.marks import SlotFrame


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
    before = [registry.copy() for registry in REGISTRIES]
    monkeypatch.syspath_prepend(str(tmp_path))

    def load(name: str, text: str):
        (tmp_path / f"{name}.py").write_text(text)
        return importlib.import_module(name)

    yield load
    for registry, kept in zip(REGISTRIES, before):
        registry.clear()
        (registry.extend if isinstance(registry, list) else registry.update)(kept)
    for name in MODULES:
        sys.modules.pop(name, None)


def test_a_view_from_a_module_of_its_own(plugin):
    from garage_exp.render.fisheye import view_remap
    from garage_exp.scene.camera import check_camera, rig_specs
    from garage_exp.scene.lenses import lens_of
    from garage_exp.scene.views import picture_lens, view_lens

    rig = compose_cfg("camera=fisheye", "camera.view=narrow", "camera.width=64", "camera.height=48").camera
    with pytest.raises(GarageError, match="camera.view: unknown view 'narrow'"):
        check_camera(rig)
    plugin("user_view", VIEW_MODULE)
    check_camera(rig)
    (spec,) = rig_specs(rig, (4.77, 1.96, 1.5))[:1]
    view = view_lens(spec)
    assert type(view).__name__ == "Narrow" and abs(view.fx - 32.0 / np.tan(np.radians(30.0))) < 1e-9
    seen = picture_lens(spec)
    assert seen.model == "pinhole" and seen.fx == view.fx  # the detector sees a pinhole view
    map_x, _, flat = view_remap(lens_of(spec), view)
    assert (flat >= 0).all() and map_x.shape == (48, 64)  # 60 degrees lie within the 190-degree lens


def test_a_lens_from_a_module_of_its_own(plugin):
    """A new camera model is one module: its lens class and `@register_lens`. The job's scene description gets a
    camera of it, the renderer's cube map and the detector read its lens, and a ground-truth box projects through
    it (the frame's lens), as the fisheye's does."""
    require("vehicles")
    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.perception.groundtruth import projected_truncation, world_corners
    from garage_exp.render.base import Frame
    from garage_exp.render.fisheye import cube_map
    from garage_exp.run.preflight import classified_plan, resolve_plan_path
    from garage_exp.scenario.assemble import build_scene
    from garage_exp.scene.camera import camera_to_world, check_camera, to_camera
    from garage_exp.scene.lenses import lens_of
    from garage_exp.scene.views import picture_lens

    cfg = compose_cfg("camera=fisheye", "camera.cameras.0.model=stereographic", "camera.cameras.0.fov=160",
                      "camera.width=128", "camera.height=96")
    with pytest.raises(GarageError, match=r"camera.cameras.0.model: unknown camera model 'stereographic' "
                                          r"\(pinhole \| fisheye\)"):
        check_camera(cfg.camera)
    plugin("user_lens", LENS_MODULE)
    check_camera(cfg.camera)
    bad = compose_cfg("camera=fisheye", "camera.cameras.0.model=stereographic", "camera.cameras.0.fov=260")
    with pytest.raises(GarageError, match="camera.cameras.0.fov: stereographic fov 260"):
        check_camera(bad.camera)

    # the job's scene description: its camera is of the new model, drawn from a cube map through the lens
    scene, setup = build_scene(scene_spec(cfg), classified_plan(resolve_plan_path(cfg.plan)), VehicleLibrary(),
                               np.random.default_rng(cfg.seed))
    (spec,) = scene.cameras
    lens = lens_of(spec)
    assert spec.model == "stereographic" and spec.fisheye and type(lens).__name__ == "Stereographic"
    assert picture_lens(spec) == lens and lens.model == "stereographic"  # the raw image: the detector's camera
    assert lens.K[0, 0] == pytest.approx(32.0 / np.tan(np.radians(40.0)))
    assert "front" in cube_map(lens).faces
    rays, inside = lens.rays()
    u, v = lens.project(rays[inside])
    grid_u, grid_v = np.meshgrid(np.arange(128) + 0.5, np.arange(96) + 0.5)
    assert np.abs(u - grid_u[inside]).max() < 1e-9 and np.abs(v - grid_v[inside]).max() < 1e-9

    # a ground-truth box through it: the target's corners land where the lens puts them, and its truncation
    shot = setup.shots[0]
    pose = camera_to_world(shot.ego, spec)
    frame = Frame(spec.name, np.zeros((96, 128, 3), np.uint8), np.zeros((96, 128), np.int32), pose, lens)
    corners = world_corners(scene.entity(shot.target), shot.poses[shot.target])
    pixels, depth = frame.project(corners)
    want = np.stack(lens.project(to_camera(pose, corners)), axis=1)
    assert np.allclose(pixels, want) and (depth > 0).all()
    assert ((pixels >= 0) & (pixels < [128, 96])).all(axis=1).any()  # the target is in view
    assert 0.0 <= projected_truncation(frame, corners) < 1.0


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
    from garage_exp.slots.detector import check_slot_detector, load
    from garage_exp.slots.schema import SlotDetectorConf

    conf = schema_node(SlotDetectorConf, {"kind": "nothing"})
    with pytest.raises(GarageError, match="slot_detector.kind: unknown kind 'nothing'"):
        check_slot_detector(conf)
    plugin("user_slots", SLOT_MODULE)
    found = load(conf)(np.zeros((30, 40, 3), np.uint8), 0.05)
    assert found.slots == [] and found.size == (40, 30) and found.meters_per_pixel == 0.05


PLUGIN_MODULE = '''
"""One of each kind a config names by a word, each registered beside what it registers."""
import numpy as np

from garage_exp.perception.detect.base import Detections, Entry
from garage_exp.perception.detect.kinds import register_entry_kind
from garage_exp.perception.sensor import register_sensor_kind
from garage_exp.slots.detector import SlotKind, register_slot_kind
from garage_exp.slots.marks import MarkingPoint, SlotFrame
from garage_exp.scene.lenses import NO_K, Fisheye, register_lens
from garage_exp.search.objectives import NOT_VISIBLE, Objective, register_objective


@register_entry_kind("centre", prefix="centre:")
class CentreBox(Entry):
    """A car in the middle half of every frame at the confidence the entry names (centre:0.8)."""

    kind = "centre"

    def __init__(self, entry, settings):
        super().__init__(entry, settings)
        self.name, self.score = "centre", float(self.entry[len("centre:"):])

    def check(self, intrinsics=None):
        self.classes = ("car",)

    def detect(self, frames, intrinsics):
        return [Detections(np.array([[f.shape[1] / 4, f.shape[0] / 4, f.shape[1] * 3 / 4, f.shape[0] * 3 / 4]],
                                    np.float32), np.array([self.score], np.float32), ["car"]) for f in frames]


def judge_missed(result, attrs):
    return None if attrs["recall"] is None else [1.0 - attrs["recall"]]


register_objective(Objective("missed", ("missed",), ("maximize",), judge_missed,
                             lambda values, attrs: f"missed {values[0]:.2f} ({attrs['frames_missed']:g} frames)",
                             NOT_VISIBLE, attrs={"frames_missed": "frames missed"}))


@register_lens("equidistant")
class Equidistant(Fisheye):
    """A fisheye whose image radius grows evenly with the angle off its axis (Kannala-Brandt with k = 0)."""

    bev = False

    @classmethod
    def check(cls, cam, rig, where):
        pass

    @classmethod
    def spec_fields(cls, cam, view):
        return {"fov": float(cam.fov), "k": NO_K, "view": view}


@register_sensor_kind("green")
def green(model, frames, rng):
    """A mono sensor behind a green filter: the green channel in all three (numpy or torch alike)."""
    return frames[..., [1, 1, 1]]


@register_slot_kind("centre_point")
class CentrePoint(SlotKind):
    """One marking point at the image's centre."""

    @staticmethod
    def load(conf):
        def detect(image, mpp):
            h, w = image.shape[:2]
            return SlotFrame([MarkingPoint(w / 2, h / 2, 0.0, "T", 1.0)], [], mpp, (w, h))
        return detect
'''


def test_one_module_of_the_users_adds_an_entry_kind_an_objective_a_lens_a_sensor_kind_and_a_slot_detector(
        plugin, tmp_path, monkeypatch):
    """Each kind is one module plus its registration: a module named in $GARAGE_EXP_PLUGINS is imported by the
    command (core.plugins.import_plugins), and each of its kinds is then used where the shipped ones are."""
    from garage_exp.core.plugins import import_plugins
    from garage_exp.perception.detect import make_detector
    from garage_exp.perception.detect.worker import DetectorProcess
    from garage_exp.slots.detector import load
    from garage_exp.slots.schema import SlotDetectorConf
    from garage_exp.core.plain import typed
    from garage_exp.scene.camera import check_camera, rig_specs
    from garage_exp.scene.lenses import lens_of
    from garage_exp.scene.schema import CameraRigConf
    from garage_exp.search import objectives
    from garage_exp.search.loop import outcome

    rig = typed(CameraRigConf, {"name": "test", "roof": True, "view": "raw", "cameras": [
        {"name": "front", "x": 0.0, "y": 0.0, "z": 0.3, "yaw": 0.0, "pitch": 0.0, "fovy": 60.0, "width": 64,
         "height": 48, "model": "equidistant", "fov": 180.0, "k": [0.0, 0.0, 0.0, 0.0]}]})  # as a job's is typed
    with pytest.raises(GarageError, match="unknown camera model 'equidistant'"):
        check_camera(rig)
    with pytest.raises(GarageError, match="model not found"):
        make_detector(models=["centre:0.8"])
    (tmp_path / "user_plugin.py").write_text(PLUGIN_MODULE)
    monkeypatch.setenv("GARAGE_EXP_PLUGINS", "user_plugin")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")])))
    import_plugins()

    # the entry kind, opened by the detector factory and run on a frame, here and in the job's detector process
    detector = make_detector(models=["centre:0.8"])
    (found,), = detector.detect([np.zeros((48, 64, 3), np.uint8)])
    assert detector.names == ["centre"] and found.scores.tolist() == pytest.approx([0.8])
    assert found.boxes.tolist() == [[16.0, 12.0, 48.0, 36.0]]
    child = DetectorProcess(threads=1)
    try:
        child.load(detector)
        child.submit(np.zeros((48, 64, 3), np.uint8))
        (theirs,) = child.result()
        assert child.names == ["centre"] and theirs.boxes.tolist() == found.boxes.tolist()
    finally:
        child.close()
    # the objective judges a job's summary, records the attribute it declares and the study shows it
    summary = {"visible_fraction_mean": 0.5, "fair_frames": 4, "frames": 10, "fair_recall": 0.75,
               "frames_missed": 1.0}
    done = outcome(summary, "missed")
    assert done.state == TrialState.COMPLETE and done.values == [0.25] and done.attrs["frames_missed"] == 1.0
    assert objectives.objective("missed").scored(done.values, done.attrs) == "missed 0.25 (1 frames)"
    assert objectives.shown()["frames_missed"] == "frames missed"
    # the lens: checked, specced, and the spec's lens projects a ray
    check_camera(rig)
    (spec,) = rig_specs(rig, (4.77, 1.96, 1.5))
    assert spec.model == "equidistant" and spec.fisheye
    lens = lens_of(spec)
    u, v = lens.project(np.array([[1.0, 0.0, 0.0], [np.sqrt(0.5), -np.sqrt(0.5), 0.0]]))
    assert u.tolist() == pytest.approx([32.0, 48.0]) and v.tolist() == pytest.approx([24.0, 24.0])  # 45 deg: r/4
    # the sensor kind processes an image
    rgb = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    seen = make_sensor(name="mono", kind="green").apply(rgb, np.random.default_rng(1))
    assert np.array_equal(seen, np.repeat(rgb[..., 1:2], 3, axis=-1))
    # the slot detector detects on a tiny image
    frame = load(schema_node(SlotDetectorConf, {"kind": "centre_point"}))(np.zeros((30, 40, 3), np.uint8), 0.05)
    assert [(p.x, p.y) for p in frame.points] == [(20.0, 15.0)] and frame.size == (40, 30)


def test_a_plugin_that_cannot_be_imported_is_one_line_naming_the_variable(monkeypatch):
    from garage_exp.core.plugins import import_plugins

    monkeypatch.setenv("GARAGE_EXP_PLUGINS", "no_such_plugin_module")
    with pytest.raises(GarageError, match=r"\$GARAGE_EXP_PLUGINS: cannot import plugin 'no_such_plugin_module': no "
                                          "module 'no_such_plugin_module' on the Python path"):
        import_plugins()
