"""The one frame pipeline: pose the actors -> render -> ground truth -> camera model -> detect -> score.

Every caller goes through it: a job's frame loop (`run.frames`, hence a search's trials, which run as jobs), the
search's pre-screen (`search.prescreen`), the gym's steps (`gym.env` and `gym.vector`: `detect_shots`) and the
benchmarks (`benchmarks/jobkit.py`).
Nothing else strings these stages together.

The stages, and the order that fixes the sensor's random stream (hence the golden tables):
- `FramePipeline.frames(shots)`: for every shot of the batch, every camera in the scene's order: render, ground
  truth, then the sensor model (drawing from `sensor_rng` in that order). A shot of another replicate re-dresses
  the materials first.
- `FramePipeline.detected(frames)`: each frame with its detections, in order. Detection overlaps rendering: frame
  k is sent to the detector (a child process, perception/detect/worker.py) before frame k+1 is rendered.
- `FramePipeline.score(item, dets)`: the target's score (`detector.iou/match/threshold`, the detector's classes).

A batch is a sequence of shots (`scenario.Shot`); on the CPU renderer they render one after another (a batch of
one at a time, as before). The GPU path (`render.batch`, `renderer.device=cuda`) renders a batch in one go.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from omegaconf import DictConfig

from garage_exp import exports
from garage_exp.perception.groundtruth import VehicleTruth
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


def replicate_materials(cfg: DictConfig, scene: Scene, replicate: int, loaded: int) -> dict:
    """Old -> new materials that turn the loaded replicate's surfaces into `replicate`'s: each replicate draws
    its own stains, cracks and (materials=random) its own grime, wetness and tint: domain randomisation within a
    job, the same draw in every cell of a sweep."""
    from garage_exp.scenario.assemble import marking_wear
    from garage_exp.scene.look import dress_for, redress

    if str(cfg.materials.level) == "none":
        return {}

    def draw(k):
        return dress_for(cfg.materials, int(cfg.seed) + k, marking_wear(cfg))

    back = redress(scene, draw(loaded))  # the scene holds replicate 0's materials; the renderer `loaded`'s
    return {back[m]: new for m, new in redress(scene, draw(replicate)).items()}


@dataclass
class FramePipeline:
    """A job's (or an environment's) frame pipeline over a loaded renderer.

    cfg: the job's composed config (look, materials, seed, dataset, detector's iou/match/threshold). sensor: the
    camera model (`perception.sensor.SensorModel` or any `apply(rgb, rng)`), drawing from `sensor_rng`.
    detector: what `detected` sends frames to (`submit`/`result`: `perception.detect.worker.open_detector`'s, or
    an in-process one); scoring: the detector's classes for `score_target` (`Detector.scoring()`).
    """

    cfg: DictConfig
    scene: Scene
    renderer: object
    sensor: object
    sensor_rng: np.random.Generator
    detector: object | None = None
    scoring: dict = field(default_factory=dict)
    dressed: int = 0  # the replicate whose materials the renderer holds (the build drew replicate 0's)

    @cached_property
    def intrinsics(self) -> dict:
        """Each camera's intrinsics by name, as its detector sees the picture."""
        from garage_exp.perception.detect import Intrinsics

        return {cam.name: Intrinsics.of(cam) for cam in self.scene.cameras}

    # -- render, ground truth, camera model ---------------------------------------------------------------------

    def pose(self, shot: Shot) -> None:
        """Move the ego and the shot's actors (one not in this variant: out of sight)."""
        from garage_exp.scenario.assemble import HIDDEN

        if shot.replicate != self.dressed and hasattr(self.renderer, "restyle"):
            self.renderer.restyle(replicate_materials(self.cfg, self.scene, shot.replicate, self.dressed))
            self.dressed = shot.replicate
        self.renderer.set_pose("ego", shot.ego)
        for name, pose in shot.poses.items():
            self.renderer.set_pose(name, pose if pose is not None else HIDDEN)

    def shoot(self, shot: Shot, camera: str, actors: Sequence[str] | None = None,
              rng: np.random.Generator | None = None) -> Rendered:
        """One camera of the posed shot: rendered, its ground truth (of `actors`, default `in_view`), the camera
        model applied (one draw from `rng`, default `sensor_rng`)."""
        from garage_exp.perception.groundtruth import ground_truth
        from garage_exp.render.composite import blank_composite

        renderer, scene = self.renderer, self.scene
        rng = self.sensor_rng if rng is None else rng
        frame = renderer.render(camera)
        names = in_view(scene, shot.poses) if actors is None else list(actors)
        truth = ground_truth(frame, renderer.unoccluded_ids(camera, names), scene, renderer.ids)
        if not scene.background and str(self.cfg.look.name) != "flat":
            # The blank control is a scene (the car alone on grey) that the camera then sees: exposure, blur
            # and noise act on the grey too. The flat look keeps the order its published tables used.
            rgb = self.sensor.apply(blank_composite(frame.rgb, frame, renderer.ids, [shot.target]), rng)
        else:
            rgb = self.sensor.apply(frame.rgb, rng)
            if not scene.background:
                rgb = blank_composite(rgb, frame, renderer.ids, [shot.target])
        target = next((t for t in truth if t.name == shot.target), None)
        # copied only when a dataset will label the frame in 3D
        geometry = exports.FrameGeometry.of(frame) if self.cfg.get("dataset") else None
        return Rendered(shot, camera, rgb, truth, target, geometry)

    def frames(self, shots: Iterable[Shot], progress: str | None = None) -> Iterator[Rendered]:
        """Every camera of every shot, in order: the sensor's random stream is drawn in this order. progress: a
        progress bar's label (None: no bar)."""
        if progress is not None:
            from tqdm import tqdm

            shots = tqdm(shots, desc=progress, unit="frame", leave=False)
        for shot in shots:
            self.pose(shot)
            for cam in self.scene.cameras:
                yield self.shoot(shot, cam.name)

    # -- detect, score ------------------------------------------------------------------------------------------

    def detected(self, frames: Iterable[Rendered]) -> Iterator[tuple[Rendered, list]]:
        """Each frame with its detections, in order, detection overlapping rendering (`overlapped`)."""
        return overlapped(frames, self.detector, self.intrinsics)

    def detect_shots(self, shots: Sequence[Shot], camera: str, actors: Sequence[Sequence[str]],
                     rngs: Sequence[np.random.Generator]) -> Iterator[tuple[Rendered, list]]:
        """A batch of shots from independent episodes (the gym's vector env: one shot per episode, each with the
        ground truth of its `actors` and its own sensor stream in `rngs`), one camera each: each frame with its
        detections, in order. On the CPU renderer the shots are posed and rendered one after another, detection
        overlapping rendering (`overlapped`). The batch is one call so that the GPU path can take it whole: a
        `render.batch.BatchRenderer` would pose the shots in its sub-scenes and render them together
        (`shoot_batch`), the detector taking the batch at once."""

        def frames():
            for shot, names, rng in zip(shots, actors, rngs, strict=True):
                self.pose(shot)
                yield self.shoot(shot, camera, names, rng)

        return self.detected(frames())

    def score(self, item: Rendered, dets: list):
        """The target's score in one frame (`perception.detect.score_target` with the job's matching rule)."""
        from garage_exp.perception.detect import score_target

        d = self.cfg.detector
        return score_target(dets, item.target, item.truth, iou_threshold=d.iou, match=d.match,
                            threshold=d.threshold, **self.scoring)


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


def shoot_batch(renderer, shots: Sequence[Shot], actors: Sequence[str], sensor, generator=None):
    """The GPU path's render, ground truth and camera model for a batch of shots, one per sub-scene of a
    `render.batch.BatchRenderer`: (frames after the camera model (N, H, W, 3) uint8 CUDA, each frame's
    `groundtruth.MaskStats` of `actors`, the rendered colour before the camera model). Only the numbers cross
    to the CPU; `groundtruth.truth_records` makes the records of a frame from its stats."""
    import torch

    from garage_exp.perception.batch_sensor import apply_batch
    from garage_exp.perception.batch_truth import batch_mask_stats, stats_of

    rgb, ids = renderer.render(shots)
    silhouettes = renderer.silhouettes(shots, actors)
    known = renderer.subs[0].ids
    actor_ids = torch.tensor([[known[m] for m in actors]] * len(shots), dtype=torch.int32, device=ids.device)
    see = torch.tensor(sorted(renderer.subs[0]._built.decal_ids), dtype=torch.int32, device=ids.device)
    stats = stats_of(batch_mask_stats(ids, silhouettes, actor_ids, see), [list(actors)] * len(shots))
    return apply_batch(sensor, rgb, generator), stats, rgb
