"""The render scene (render/batch.py): ONE object owning N sub-scenes behind `render_batch`. On the CPU a batch of
two sub-scenes gives exactly the frames, ground truth and frame table of two separate jobs; the CUDA branch is
refused in one line without a GPU."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import compose_cfg, require, run_app

from garage_exp.core.errors import GarageError
from garage_exp.run.spec import scene_spec

ROOT = Path(__file__).resolve().parent.parent
# Two frames of case 1 on the tiny plan, at a tiny size.
SMALL = ("plan=tiny", "case.motion.start=5", "case.motion.end=4", "case.motion.step=1", "camera.width=64",
         "camera.height=48")


@pytest.mark.render
@pytest.mark.slow
def test_a_batch_of_two_sub_scenes_renders_what_two_separate_jobs_render():
    require("vulkan", "vehicles")
    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.core.plugins import build
    from garage_exp.plan import classify, load_plan
    from garage_exp.render.batch import RenderScene
    from garage_exp.render.sapien_backend import get_renderer
    from garage_exp.run.pipeline import FramePipeline, in_view
    from garage_exp.scenario.assemble import HIDDEN, build_scene

    cfg = compose_cfg(*SMALL)
    scene, setup = build_scene(scene_spec(cfg), classify(load_plan(ROOT / "plans" / "tiny.yaml")), VehicleLibrary(),
                               np.random.default_rng(cfg.seed))
    shots = setup.shots[:2]
    assert len(shots) == 2 and shots[0].ego != shots[1].ego
    sensor = build(cfg.sensor, "a sensor model", "sensor._target_")  # the camera kind: noise from each stream
    cameras = [cam.name for cam in scene.cameras]
    actors = [in_view(scene, shot.poses) for shot in shots]

    def alone(shot, names):  # a job of one shot: a freshly loaded renderer, its own sensor stream
        renderer = get_renderer(max_lights=cfg.renderer.max_lights)
        renderer.load(scene)
        pipeline = FramePipeline(cfg, scene, renderer, sensor, np.random.default_rng(7))
        return list(pipeline.shots([shot], cameras, [names], [pipeline.sensor_rng]))

    separate = [item for shot, names in zip(shots, actors) for item in alone(shot, names)]

    first = get_renderer(max_lights=cfg.renderer.max_lights)
    first.load(scene)
    stage = RenderScene([first, first.sibling()], HIDDEN)
    stage.load(scene)
    pipeline = FramePipeline(cfg, scene, stage, sensor, np.random.default_rng(7))
    batched = list(pipeline.shots(shots, cameras, actors, [np.random.default_rng(7), np.random.default_rng(7)]))

    assert stage.subs[1].poses[stage.subs[1].ego] == shots[1].ego  # shot 1 was posed in sub-scene 1
    assert [(b.shot.index, b.camera) for b in batched] == [(s.shot.index, s.camera) for s in separate]
    for a, b in zip(separate, batched):
        assert np.array_equal(a.rgb, b.rgb)
        assert a.truth == b.truth and a.target == b.target
    assert any(t.visible_pixels for item in batched for t in item.truth)  # something was seen
    with pytest.raises(ValueError, match="3 shots for 2 sub-scenes"):
        stage.render_batch([shots[0]] * 3, cameras, [[]] * 3)


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_a_job_in_two_sub_scenes_writes_the_table_of_one_in_one(tmp_path, mlflow_uri):
    require("vulkan", "vehicles", "models")
    tables = []
    for scenes in (1, 2):
        out = tmp_path / f"scenes{scenes}"
        out.mkdir()
        proc = run_app([*SMALL, "detector.imgsz=64", "renderer.save_frames=none", f"renderer.scenes={scenes}",
                        f"tracking.uri={mlflow_uri}"], out)
        assert proc.returncode == 0, proc.stderr[-3000:]
        tables.append(pd.read_csv(out / "run" / "frames.csv"))
    assert len(tables[0]) == 4 and tables[0].visible_fraction.gt(0).any()  # two colours x two positions
    pd.testing.assert_frame_equal(tables[0], tables[1])


def test_the_cuda_branch_is_refused_in_one_line_without_a_gpu():
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is here")
    from omegaconf import OmegaConf

    from garage_exp.render.open import open_renderer
    from garage_exp.scene.description import Pose

    conf = OmegaConf.create({"backend": "sapien", "device": "cuda", "scenes": 4})
    with pytest.raises(GarageError, match="^renderer.device: renderer.device=cuda needs a CUDA GPU"):
        open_renderer(conf, Pose())
