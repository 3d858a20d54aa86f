"""The one frame pipeline (run/pipeline.py): no second copy of its sequence in the project, and its stages on a
tiny scene drawn by a stand-in renderer (plain arrays: the order of the sensor's random stream, ground truth
from the renderer's ids, the overlapped detection)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from garage_exp.perception.sensor import make_sensor
from garage_exp.render import Frame
from garage_exp.run.pipeline import FramePipeline, in_view
from garage_exp.scenario import Shot
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import CameraSpec, Entity, Pose, Scene
from garage_exp.core.plain import Settings
from garage_exp.perception.detect.matching import Scoring
from garage_exp.run.spec import FrameConf

RULE = Scoring(threshold=0.5, iou=0.5, match="full")


def frame_conf(look: str) -> FrameConf:
    """What the pipeline is told of a job without materials, wear or dataset, under `look`."""
    return FrameConf(look, Settings({"level": "none"}), 0, 0.0, False)

ROOT = Path(__file__).resolve().parent.parent
# The stages a rendered frame goes through; a module that calls them on a render copies the pipeline. (Scoring
# alone is also done on saved pictures: loop/evaluate.py, bench_detect.py.)
STAGES = [r"\bground_truth\(", r"\bblank_composite\(", r"sensor\.apply\("]


def test_no_second_copy_of_the_frame_sequence():
    """Only run/pipeline.py calls ground truth, the blank composite and the sensor model on rendered frames
    (their own modules and tests aside)."""
    own = {"perception/groundtruth.py", "render/composite.py", "perception/sensor.py", "run/pipeline.py",
           "blank_factors.py"}  # the blank control's study takes the stages apart on purpose: each factor alone
    offenders = []
    for path in [*(ROOT / "garage_exp").rglob("*.py"), *(ROOT / "benchmarks").rglob("*.py")]:
        rel = path.relative_to(ROOT / "garage_exp").as_posix() if "garage_exp" in path.parts else path.name
        if rel in own:
            continue
        text = path.read_text()
        offenders += [f"{rel}: {s}" for s in STAGES if re.search(s, text)]
    assert not offenders, offenders


class Drawn:
    """A stand-in renderer: a 40x30 frame where the target covers a block that moves with its pose."""

    ids = {"target": 3, "ego": 9}

    def __init__(self):
        self.poses = {}

    def set_pose(self, name, pose):
        self.poses[name] = pose

    def render(self, camera):
        spec = CameraSpec(camera, Pose(0.0, 0.0, 1.0), width=40, height=30)
        ids = np.zeros((30, 40), np.int32)
        x = int(self.poses["target"].y) + 10
        ids[10:20, x:x + 8] = 3
        rgb = np.full((30, 40, 3), 90, np.uint8)
        rgb[ids == 3] = 200
        return Frame(camera, rgb, ids, camera_to_world(self.poses["ego"], spec), lens_of(spec),
                     {"target": self.poses["target"]})

    def unoccluded_ids(self, camera, names):
        frame = self.render(camera)
        return {n: frame.ids == self.ids[n] for n in names}


def test_frames_draw_the_sensor_stream_in_shot_then_camera_order():
    scene = Scene("s", [Entity("target", "target", Pose(10.0, 0.0, 0.0, 90.0), extent=(4.5, 1.8, 1.5),
                               static=False)],
                  cameras=[CameraSpec("front", Pose(0.0, 0.0, 1.0), width=40, height=30),
                           CameraSpec("rear", Pose(0.0, 0.0, 1.0, 180.0), width=40, height=30)])
    conf = frame_conf("flat")
    shots = [Shot(k, "", float(k), Pose(), {"target": Pose(10.0, float(k), 0.0, 90.0)}, "target") for k in range(3)]
    noisy = make_sensor(name="camera", kind="camera", params={})
    got = list(FramePipeline(conf, scene, Drawn(), noisy, np.random.default_rng(4), rule=RULE).frames(shots))
    assert [(f.shot.index, f.camera) for f in got] == [(k, c) for k in range(3) for c in ("front", "rear")]
    rng, renderer = np.random.default_rng(4), Drawn()
    for f in got:
        renderer.set_pose("ego", f.shot.ego)
        renderer.set_pose("target", f.shot.poses["target"])
        assert np.array_equal(f.rgb, noisy.apply(renderer.render(f.camera).rgb, rng))
        assert f.target.full_box == (10 + f.shot.index, 10, 18 + f.shot.index, 20)
    assert in_view(scene, {"target": None}) == [] and in_view(scene, {}) == ["target"]
    assert in_view(scene, {}, placed_only=True) == []


def test_a_frame_of_torch_tensors_finishes_as_its_numpy_twin():
    """The GPU branch hands the pipeline frames as tensors: ground truth, the blank composite and the camera model
    take them through the same code (CPU tensors here) and give the numpy frame's truth, and its picture within
    one 8-bit level (float32 sums in another order)."""
    import torch

    from garage_exp.render.batch import Take

    scene = Scene("s", [Entity("target", "target", Pose(10.0, 0.0, 0.0, 90.0), extent=(4.5, 1.8, 1.5),
                               static=False)],
                  cameras=[CameraSpec("front", Pose(0.0, 0.0, 1.0), width=40, height=30)], background=False)
    conf = frame_conf("real")
    renderer = Drawn()
    shot = Shot(0, "", 0.0, Pose(), {"target": Pose(10.0, 2.0, 0.0, 90.0)}, "target")
    renderer.set_pose("ego", shot.ego)
    renderer.set_pose("target", shot.poses["target"])
    frame = renderer.render("front")
    masks = renderer.unoccluded_ids("front", ["target"])
    tensor_frame = Frame("front", torch.from_numpy(frame.rgb), torch.from_numpy(frame.ids), frame.cam_to_world,
                         frame.lens, frame.poses)
    sensor = make_sensor(name="camera", kind="camera", params={"blur_sigma": 0.8, "vignetting": 0.3})
    pipeline = FramePipeline(conf, scene, renderer, sensor, np.random.default_rng(0), rule=RULE)
    want = pipeline.finish(Take(shot, "front", frame, masks, renderer.ids), np.random.default_rng(5))
    got = pipeline.finish(Take(shot, "front", tensor_frame, {k: torch.from_numpy(m) for k, m in masks.items()},
                               renderer.ids), np.random.default_rng(5))
    assert isinstance(got.rgb, np.ndarray) and got.truth == want.truth and got.target.visible_fraction == 1.0
    assert np.abs(got.rgb.astype(int) - want.rgb.astype(int)).max() <= 1
