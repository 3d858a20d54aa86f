"""The one frame pipeline: pose the actors -> render -> ground truth -> camera model -> detect -> score.

Every caller goes through it: a job's frame loop (`run.frames`, hence a search batch's trials, which run as jobs),
the search's pre-screen (`search.prescreen`), the gym's steps (`gym.env` and `gym.vector`: `detect_shots`) and the
benchmarks (`benchmarks/jobkit.py`, `benchmarks/performance/gpu_pipeline.py`).
Nothing else strings these stages together.

It always works in batches: the shots go to the render scene (`render.batch.RenderScene`, N sub-scenes) N at a
time, through its one render call, `render_batch`; on the CPU N is 1 unless `renderer.scenes` says otherwise,
under `renderer.device=cuda` the N sub-scenes render as one group on the GPU. Ground truth and the camera model
take the pictures as they come (numpy, or torch on the GPU).

The stages, and the order that fixes the sensor's random stream (hence the golden tables):
- `FramePipeline.frames(shots)`: for every shot of the batch, every camera in the scene's order: render, ground
  truth, then the sensor model (drawing from `sensor_rng` in that order). A shot of another replicate re-dresses
  the materials of its sub-scene first.
- `FramePipeline.detected(frames)`: each frame with its detections, in order. Detection overlaps rendering: frame
  k is sent to the detector (a child process, perception/detect/worker.py) before the next batch is rendered.
- `FramePipeline.score(item, dets)`: the target's score (`detector.iou/match/threshold`, the detector's classes).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from typing import Any

from omegaconf import DictConfig

from garage_exp import exports
from garage_exp.perception.detect.matching import Scoring
from garage_exp.perception.groundtruth import VehicleTruth
from garage_exp.render.batch import RenderScene, Take
from garage_exp.run.spec import FrameConf
from garage_exp.scenario import Shot
from garage_exp.scene.description import Scene


@dataclass
class Rendered:
    """One camera's frame as the detectors see it (after the sensor model), with its ground truth."""

    shot: Shot
    camera: str
    rgb: np.ndarray
    truth: list[VehicleTruth]
    target: VehicleTruth | None
    geometry: exports.FrameGeometry | None  # the camera and the actors' poses, for the dataset's 3D labels


def in_view(scene: Scene, poses: dict, placed_only: bool = False) -> list[str]:
    """The actors whose unoccluded silhouettes ground truth needs: every vehicle and person placed in the shot
    (`poses`: None for one not in this variant; an actor absent from it stands where the scene put it, unless
    `placed_only`)."""
    return [v.name for v in scene.actors()
            if v.role != "ego" and v.kind != "box" and poses.get(v.name, None if placed_only else v.pose)]


def replicate_materials(conf: FrameConf, scene: Scene, replicate: int, loaded: int) -> dict:
    """Old -> new materials that turn the loaded replicate's surfaces into `replicate`'s: each replicate draws
    its own stains, cracks and (materials=random) its own grime, wetness and tint: domain randomisation within a
    job, the same draw in every cell of a sweep."""
    from garage_exp.scene.look import dress_for, redress

    if str(conf.materials.level) == "none":
        return {}

    def draw(k):
        return dress_for(conf.materials, conf.seed + k, conf.wear)

    back = redress(scene, draw(loaded))  # the scene holds replicate 0's materials; the renderer `loaded`'s
    return {back[m]: new for m, new in redress(scene, draw(replicate)).items()}


def batches(items: Iterable, size: int) -> Iterator[list]:
    """`items` in lists of `size` (the last may be shorter), read lazily."""
    batch = []
    for item in items:
        batch.append(item)
        if len(batch) == size:
            yield batch
            batch = []
    if batch:
        yield batch


@dataclass
class FramePipeline:
    """A job's (or an environment's) frame pipeline over a render scene.

    conf: the job spec's `FrameConf` (look, materials, seed, wear, dataset), with `rule` its matching rule; or a
    config (tests, benchmarks), read here once, whose `detector` group gives the rule unless `rule` does. renderer: a
    `render.batch.RenderScene` (N sub-scenes), or one loaded `Renderer`, which becomes a scene of one sub-scene.
    sensor: the camera model (`perception.sensor.SensorModel` or any `apply(rgb, rng)`), drawing from
    `sensor_rng`. detector: what `detected` sends frames to (`submit`/`result`:
    `perception.detect.worker.open_detector`'s, or an in-process one); scoring: the detector's classes for
    `score_target` (`Detector.scoring()`).
    """

    conf: FrameConf | Any  # a config node or its Settings is read into a FrameConf
    scene: Scene
    renderer: object
    sensor: object
    sensor_rng: np.random.Generator
    detector: object | None = None
    scoring: dict = field(default_factory=dict)
    rule: Scoring | None = None  # the job spec's matching rule; None: a config's `detector` group's

    def __post_init__(self) -> None:
        from garage_exp.core.plain import settings
        from garage_exp.scenario.assemble import HIDDEN

        if not isinstance(self.conf, FrameConf):  # a config (tests, benchmarks): read once, here
            cfg = settings(self.conf)
            self.conf = FrameConf.of_config(cfg)
            self.rule = self.rule or Scoring.of(cfg.detector)
        if self.rule is None:
            raise TypeError("a FrameConf comes with its job spec's matching rule (rule=spec.scoring)")
        self.stage = (self.renderer if isinstance(self.renderer, RenderScene)
                      else RenderScene.over(self.renderer, HIDDEN))

    @cached_property
    def intrinsics(self) -> dict:
        """Each camera's lens by name, as its detector sees the picture (scene/views.picture_lens)."""
        from garage_exp.scene.views import picture_lens

        return {cam.name: picture_lens(cam) for cam in self.scene.cameras}

    # -- render, ground truth, camera model ---------------------------------------------------------------------

    def redress(self, replicate: int, loaded: int) -> dict:
        """The material change from the loaded replicate's surfaces to `replicate`'s (`replicate_materials`)."""
        return replicate_materials(self.conf, self.scene, replicate, loaded)

    def shots(self, shots: Sequence[Shot], cameras: Sequence[str], actors: Sequence[Sequence[str]],
              rngs: Sequence[np.random.Generator]) -> Iterator[Rendered]:
        """Every camera of every shot, in order, rendered N at a time (`RenderScene.render_batch`), then each
        frame's ground truth and camera model (drawing from its shot's rng) in that order."""
        n = self.stage.n
        for start in range(0, len(shots), n):
            takes = self.stage.render_batch(shots[start:start + n], cameras, actors[start:start + n], self.redress)
            per_shot = len(cameras)
            for k, take in enumerate(takes):
                yield self.finish(take, rngs[start + k // per_shot])

    def finish(self, take: Take, rng: np.random.Generator) -> Rendered:
        """A rendered camera's ground truth (of its silhouettes' actors) and camera model (one draw from `rng`).
        The frame leaves as numpy (the detector's and the tables' input)."""
        from garage_exp.perception.groundtruth import ground_truth
        from garage_exp.render.composite import blank_composite, contact_shadow

        shot, frame, scene, ids = take.shot, take.frame, self.scene, take.ids
        truth = ground_truth(frame, take.silhouettes, scene, ids)
        if not scene.background and self.conf.look != "flat":
            # The blank control is a scene (the car alone on grey, with its own contact shadow, under the look's
            # blank_light) that the camera then sees: exposure, blur and noise act on the grey too. The flat look
            # keeps the order its published tables used.
            pose = frame.poses.get(shot.target) or shot.poses.get(shot.target)  # None: not placed, no shadow
            shadow = None if pose is None else contact_shadow(frame, scene.entity(shot.target), pose)
            rgb = self.sensor.apply(blank_composite(frame.rgb, frame, ids, [shot.target], shadow), rng)
        else:
            rgb = self.sensor.apply(frame.rgb, rng)
            if not scene.background:
                rgb = blank_composite(rgb, frame, ids, [shot.target])
        target = next((t for t in truth if t.name == shot.target), None)
        if not isinstance(rgb, np.ndarray):  # a GPU frame: the detector's worker and the tables take numpy
            rgb = rgb.cpu().numpy()
        # copied only when a dataset will label the frame in 3D
        geometry = exports.FrameGeometry.of(frame) if self.conf.dataset else None
        return Rendered(shot, take.camera, rgb, truth, target, geometry)

    def frames(self, shots: Iterable[Shot], progress: str | None = None) -> Iterator[Rendered]:
        """Every camera of every shot, in order: the sensor's random stream is drawn in this order. progress: a
        progress bar's label (None: no bar)."""
        if progress is not None:
            from tqdm import tqdm

            shots = tqdm(shots, desc=progress, unit="frame", leave=False)
        cameras = [cam.name for cam in self.scene.cameras]
        for batch in batches(shots, self.stage.n):
            actors = [in_view(self.scene, shot.poses) for shot in batch]
            yield from self.shots(batch, cameras, actors, [self.sensor_rng] * len(batch))

    # -- detect, score ------------------------------------------------------------------------------------------

    def detected(self, frames: Iterable[Rendered]) -> Iterator[tuple[Rendered, list]]:
        """Each frame with its detections, in order, detection overlapping rendering (`overlapped`)."""
        return overlapped(frames, self.detector, self.intrinsics)

    def detect_shots(self, shots: Sequence[Shot], camera: str, actors: Sequence[Sequence[str]],
                     rngs: Sequence[np.random.Generator]) -> Iterator[tuple[Rendered, list]]:
        """A batch of shots from independent episodes (the gym's vector env: one shot per episode, each with the
        ground truth of its `actors` and its own sensor stream in `rngs`), one camera each: each frame with its
        detections, in order. The shots render N at a time in the render scene's sub-scenes (one after another
        on the CPU's single sub-scene, as one group on the GPU), detection overlapping rendering."""
        return self.detected(self.shots(list(shots), [camera], list(actors), list(rngs)))

    def score(self, item: Rendered, dets: list):
        """The target's score in one frame (`perception.detect.score_target` with the job's matching rule)."""
        return self.rule.score(dets, item.target, item.truth, **self.scoring)


def overlapped(frames: Iterable[Rendered], detector, cameras: dict) -> Iterator[tuple[Rendered, list]]:
    """Each frame with its detections, in order. Frame k is submitted (with its camera's intrinsics, `cameras`
    by name) before frame k+1 is rendered, so the detector (a child process) works on k while this process
    renders k+1."""
    waiting: deque[Rendered] = deque()
    rendered = iter(frames)
    while True:
        try:
            frame = next(rendered)
        except StopIteration:
            break
        except Exception as exc:
            # Rendering failed: the frame already sent still gets its row, as the serial loop would have kept it.
            while waiting:
                yield waiting.popleft(), detector.result()
            raise exc
        detector.submit(frame.rgb, cameras.get(frame.camera))
        waiting.append(frame)
        if len(waiting) > 1:
            yield waiting.popleft(), detector.result()
    while waiting:
        yield waiting.popleft(), detector.result()


def render_frames(cfg: DictConfig, scene: Scene, shots: Iterable[Shot], renderer, sensor,
                  sensor_rng: np.random.Generator) -> Iterator[Rendered]:
    """The render half of the pipeline for callers that detect on their own (the pre-screen's in-process
    detector, the benchmarks and tests of the render stage): every camera of every shot, in order."""
    return FramePipeline(cfg, scene, renderer, sensor, sensor_rng).frames(shots)
