"""The render scene: ONE object owning N sub-scenes, whose `render_batch(shots)` is the only render call (the
ManiSkill way: its `ManiSkillScene` over sub-scenes). Every caller of the frame pipeline (`run.pipeline`: a job's
frames, hence a search batch's trials, the pre-screen, the gym's envs, the benchmarks) renders through it, and
gets it from the one opener, `render.open.open_renderer` (the backend the config names, render/registry.py).

A batch is up to N shots: shot i is posed in sub-scene i, and each of its cameras rendered with the unoccluded
silhouettes of the actors ground truth asks for (`Take`). This class is the batch every backend gets for free:
each sub-scene a `Renderer` of its own (sub-scene 0 the process's warm one, the others its `sibling()`s), rendered
one after another through the `Renderer` interface (render/base.py) and nothing else: numpy pictures, exactly
those of N separate jobs (tests/test_render_scene.py). A backend that batches on its own (SAPIEN's CUDA group,
render/sapien_batch.py) subclasses it and overrides `load` and `render_batch`; its callers see no difference.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from garage_exp.render.base import Frame, Renderer
from garage_exp.scene.description import Pose


@dataclass
class Take:
    """One camera of one shot, rendered: its frame (numpy, or torch CUDA tensors in `rgb` and `ids`), the
    unoccluded silhouettes (name -> H x W bool) of the actors asked for (one left out is outside the image) and
    the entity ids of the sub-scene that rendered it (a sub-scene kept from an earlier scene numbers its new
    actors on from the old ones)."""

    shot: object
    camera: str
    frame: Frame
    silhouettes: dict
    ids: dict


class RenderScene:
    """N sub-scenes of one scene description behind one `render_batch` (see the module's doc). subs: the
    sub-scenes' renderers (`Renderer`s); hidden: where an actor absent from a shot waits (out of sight)."""

    def __init__(self, subs: Sequence[Renderer], hidden: Pose):
        if not subs:
            raise ValueError("a render scene needs at least one sub-scene")
        self.subs, self.hidden = list(subs), hidden
        self.dressed = [0] * len(self.subs)  # the replicate whose materials each sub-scene holds

    @classmethod
    def over(cls, renderer: Renderer, hidden: Pose) -> "RenderScene":
        """One sub-scene: a renderer already loaded (the CPU path's batch of one)."""
        return cls([renderer], hidden)

    @classmethod
    def of(cls, first: Renderer, n: int, hidden: Pose) -> "RenderScene":
        """`n` sub-scenes: `first` (the process's renderer) and n - 1 of its siblings."""
        return cls([first, *(first.sibling() for _ in range(n - 1))], hidden)

    @property
    def n(self) -> int:
        """Sub-scenes: the most shots a batch holds."""
        return len(self.subs)

    @property
    def ids(self) -> dict[str, int]:
        """Entity name -> id in the pictures (the same in every sub-scene: each is built in the same order)."""
        return self.subs[0].ids

    @property
    def description(self):
        """The scene description every sub-scene holds (None before a load)."""
        return self.subs[0].description

    def load(self, scene) -> None:
        """Build every sub-scene from the description (a sub-scene that holds it already is kept)."""
        for k, sub in enumerate(self.subs):
            if sub.description is not scene:
                sub.load(scene)
                self.dressed[k] = 0

    def render_batch(self, shots: Sequence, cameras: Sequence[str], actors: Sequence[Sequence[str]],
                     redress: Callable[[int, int], dict] | None = None) -> list[Take]:
        """Up to `n` shots, shot i in sub-scene i: every camera of `cameras` (in order) of every shot (in order),
        with the silhouettes of the shot's `actors`. redress(replicate, loaded): the material change that turns
        the loaded replicate's surfaces into the shot's (None: replicates look alike)."""
        if len(shots) > self.n:
            raise ValueError(f"{len(shots)} shots for {self.n} sub-scenes")
        if len(actors) != len(shots):
            raise ValueError(f"{len(actors)} actor lists for {len(shots)} shots")
        for k, shot in enumerate(shots):
            if redress is not None and shot.replicate != self.dressed[k]:
                self.subs[k].restyle(redress(shot.replicate, self.dressed[k]))
                self.dressed[k] = shot.replicate
        return self.takes(shots, cameras, actors)

    def takes(self, shots: Sequence, cameras: Sequence[str], actors: Sequence[Sequence[str]]) -> list[Take]:
        """The batch's pictures, the sub-scenes dressed: each shot posed in its sub-scene, then rendered."""
        takes = []
        for k, shot in enumerate(shots):
            sub = self.subs[k]
            sub.set_pose("ego", shot.ego)
            for name, pose in shot.poses.items():
                sub.set_pose(name, pose if pose is not None else self.hidden)
            for camera in cameras:
                frame = sub.render(camera)
                takes.append(Take(shot, camera, frame, sub.unoccluded_ids(camera, actors[k]), sub.ids))
        return takes
