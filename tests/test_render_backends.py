"""A second renderer backend is one module plus its registration (render/registry.py): a tiny backend written here,
numpy only, that draws the scene description's boxes (an actor's mesh as its extent) as a depth picture and a
segmentation, registered from a temporary module named in $GARAGE_EXP_PLUGINS, renders a job through the job's
own pipeline, batched by the generic render scene, without SAPIEN; its frame table carries ground truth."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from garage_exp.core.errors import GarageError

DEPTH_BOXES = '''
"""Depth-only boxes: each entity's boxes (a mesh: its extent) ray-cast in numpy; colour is grey by depth."""
import numpy as np

from garage_exp.render import Frame, register_backend
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import Box, Mesh, Pose

MADE = []  # every renderer made, so the test sees the sub-scenes


class DepthBoxes:
    description = None

    def __init__(self, far):
        self.far, self.poses, self.boxes, self._ids, self.loads = float(far), {}, {}, {}, 0
        MADE.append(self)

    def load(self, scene):
        self.description, self.loads = scene, self.loads + 1
        self.cameras = {c.name: c for c in scene.cameras}
        self.poses = {e.name: e.pose for e in scene.entities}
        self._ids = {e.name: k + 1 for k, e in enumerate(scene.entities)}
        self.boxes = {}  # name -> [(centre offset, yaw offset, half size)] in the entity's frame
        for e in scene.entities:
            if e.role == "ego":
                continue  # the cameras ride inside it
            parts = [(s.offset, np.asarray(s.size) / 2) for s in e.shapes if isinstance(s, Box)]
            if e.extent is not None and any(isinstance(s, Mesh) for s in e.shapes):
                length, width, height = e.extent
                parts.append((Pose(0.0, 0.0, height / 2), np.array([length, width, height]) / 2))
            if parts:
                self.boxes[e.name] = parts

    @property
    def ids(self):
        return dict(self._ids)

    def set_pose(self, name, pose):
        self.poses[name] = pose

    def restyle(self, change):
        pass  # no materials: replicates look alike

    def sibling(self):
        return DepthBoxes(self.far)

    def _cast(self, camera, names):
        """(depth, ids) of the named entities' boxes as the camera sees them (z-buffered)."""
        spec = self.cameras[camera]
        pose = camera_to_world(self.poses["ego"], spec)
        lens = lens_of(spec)
        fx, fy, cx, cy = lens.fx, lens.fy, lens.cx, lens.cy
        v, u = np.mgrid[0:spec.height, 0:spec.width] + 0.5
        local = np.stack([np.ones_like(u), (cx - u) / fx, (cy - v) / fy], -1).reshape(-1, 3)
        rays, origin = local @ pose[:3, :3].T, pose[:3, 3]  # x = 1 along the view axis: t is the depth
        depth, ids = np.full(len(rays), np.inf), np.zeros(len(rays), np.int32)
        for name in names:
            for offset, half in self.boxes.get(name, ()):
                box = self.poses[name].compose(offset)
                c, s = np.cos(np.radians(box.yaw)), np.sin(np.radians(box.yaw))
                turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # world -> the box's axes
                o, d = turn @ (origin - [box.x, box.y, box.z]), rays @ turn.T
                with np.errstate(divide="ignore", invalid="ignore"):
                    t1, t2 = (-half - o) / d, (half - o) / d
                near = np.nanmax(np.minimum(t1, t2), axis=1)
                far = np.nanmin(np.maximum(t1, t2), axis=1)
                hit = (near <= far) & (near > spec.near) & (near < depth)
                depth[hit], ids[hit] = near[hit], self._ids[name]
        return depth.reshape(spec.height, spec.width), ids.reshape(spec.height, spec.width), pose

    def render(self, camera):
        depth, ids, pose = self._cast(camera, self.boxes)
        grey = np.where(np.isfinite(depth), 255 * (1 - np.clip(depth / self.far, 0, 1)), 0).astype(np.uint8)
        vehicles = {e.name for e in self.description.vehicles()}
        return Frame(camera, np.repeat(grey[..., None], 3, -1), ids, pose, lens_of(self.cameras[camera]),
                     {n: p for n, p in self.poses.items() if n in vehicles},
                     pillars=frozenset(self._ids[e.name] for e in self.description.entities if e.is_pillar))

    def unoccluded_ids(self, camera, names):
        out = {}
        for name in names:
            mask = self._cast(camera, [name])[1] > 0
            if mask.any():
                out[name] = mask
        return out


@register_backend("depthboxes", says="depth-only boxes in numpy (a test's)")
def make(*, far=60.0):
    return DepthBoxes(far)
'''


@pytest.fixture
def depth_boxes(tmp_path, monkeypatch):
    """The backend's module written to a temporary folder and named in $GARAGE_EXP_PLUGINS, imported afresh by the
    test (its registration undone after it); SAPIEN's factory made to fail, so that a job that asked it would say
    so."""
    import sys

    import garage_exp.render.sapien_backend as sapien_backend  # the shipped backend registered before the copy
    from garage_exp.render import registry

    (tmp_path / "depth_boxes.py").write_text(DEPTH_BOXES)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("GARAGE_EXP_PLUGINS", "depth_boxes")
    monkeypatch.delitem(sys.modules, "depth_boxes", raising=False)
    monkeypatch.setattr(registry, "BACKENDS", dict(registry.BACKENDS))

    def no_sapien(**_):
        raise AssertionError("the SAPIEN renderer was asked for")

    monkeypatch.setattr(sapien_backend, "get_renderer", no_sapien)
    return tmp_path


@pytest.mark.detect
def test_a_job_renders_through_a_backend_registered_from_a_plugin_module(depth_boxes, tmp_path):
    """`renderer.backend=depthboxes` in two sub-scenes (the generic batch, `sibling`): every frame of the job is
    the plugin's picture, and ground truth sees the target in it."""
    import sys

    import pandas as pd
    from conftest import require, run_app

    require("vehicles", "models")
    r = run_app(["plan=tiny", "case.motion.start=5.0", "case.motion.end=3.0", "case.motion.step=1.0",
                 "palette.target_colours=[black]", "detector.models=[yolov8n_int8_openvino_model]",
                 "detector.imgsz=64", "camera.width=96", "camera.height=64", "renderer.backend=depthboxes",
                 "renderer.scenes=2", "renderer.save_frames=none", f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"],
                tmp_path, {"GARAGE_EXP_PLUGINS": "depth_boxes"})
    assert r.returncode == 0, r.stderr[-3000:]
    made = sys.modules["depth_boxes"].MADE
    assert len(made) == 2 and all(m.loads == 1 for m in made)  # sub-scene 0 and its sibling, each loaded once
    table = pd.read_csv(tmp_path / "run" / "frames.csv")
    assert table.position.tolist() == [5.0, 4.0, 3.0]
    assert table.visible_fraction.gt(0).any() and table.box_height.gt(0).any()  # the target, seen in boxes
    assert OmegaConf.load(tmp_path / "run" / "config.yaml").renderer.backend == "depthboxes"


def test_the_prescreen_opens_the_backend_the_job_opens(depth_boxes):
    """The search's pre-screen (ground truth only) renders through the same opener and pipeline."""
    import sys

    from conftest import compose_cfg, require

    from garage_exp.core.plugins import import_plugins
    from garage_exp.search.prescreen import frames_table

    require("vehicles")
    import_plugins()  # as every command's shell does
    cfg = compose_cfg("plan=tiny", "case.motion.start=5.0", "case.motion.end=4.0", "case.motion.step=1.0",
                      "palette.target_colours=[black]", "renderer.backend=depthboxes")
    table, setup = frames_table(cfg, None, 0.5)
    assert len(table) == len(setup.shots) == 2 and table.visible_fraction.gt(0).any()
    assert len(sys.modules["depth_boxes"].MADE) == 1  # renderer.scenes=1: one sub-scene


def test_an_unknown_backend_is_one_line_naming_the_key():
    from garage_exp.render.open import check_renderer

    conf = OmegaConf.create({"backend": "blender", "save_frames": "key", "scenes": 1})
    with pytest.raises(GarageError) as info:
        check_renderer(conf)
    assert info.value.where == "renderer.backend" and "unknown renderer backend 'blender'" in str(info.value)


def test_the_default_backend_keeps_the_identity_of_jobs_run_before_the_key_existed():
    """`renderer.backend=sapien` is left out of a job's config hash (an earlier run of the same config is still
    found); another backend is another job."""
    from conftest import compose_cfg

    from garage_exp.tracking.provenance import config_hash

    cfg = compose_cfg()
    before = OmegaConf.to_container(cfg, resolve=True)
    del before["renderer"]["backend"]  # the config as composed before the key existed
    assert config_hash(cfg) == config_hash(OmegaConf.create(before))
    assert config_hash(compose_cfg("renderer.backend=other")) != config_hash(cfg)
