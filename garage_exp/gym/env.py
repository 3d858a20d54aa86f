"""The Gymnasium environment `garage_exp/StepOut-v0`: the ego drives the case's path at `ego.speed` while an
adversary moves a person (how fast, when, where in the gap) so that the detectors confirm it too late to stop.
`garage_exp/PullOut-v0` (PullOutEnv) is the same on case=pullout with a car's `gap` moved: when and how fast it
pulls out of its bay towards the ego's path. Any actor's placement value can be a mover (`gym.movers`).

Each step is one frame: time advances by the ego's step over its speed, the adversary's action moves its values
within physical limits (limits.py), the ego's front camera renders the scene and the detectors score the target,
through the frame pipeline a job uses (garage_exp/run/pipeline.py), in the process's warm renderer and detector
child: a step is a batch of one frame (`shoot`), waited for; the vector env (vector.py) steps K episodes' frames as
one batch. The scene is built once per environment with every actor in it; a step only moves them.

Observation (a Box, not pixels): time, the ego's speed, its distance before the target's spot, the critical
distance, the camera's range to the target, the last frame's confidence, the share of the last n frames that
were hits, whether the target is confirmed, whether it was fairly visible before the critical distance yet, and
each moved value with its velocity.

Reward: 1 at the end of an episode the target was fairly visible in before the critical distance and confirmed
only inside it, or never (late, garage_exp/results/late.py), provided a perfect detector could have confirmed it in
time (k fair frames within n before the critical distance: one fair peek between two hidings is no test); plus
`gym.shaping` x (1 - confidence) on each fair frame before the critical distance. A target never fairly visible in
time earns nothing, hidden or not. `gym.objective=hard` rewards a hard-and-fair episode instead.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import asdict

import gymnasium
import numpy as np
from gymnasium import spaces
from omegaconf import DictConfig, OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.core.plain import settings
from garage_exp.gym import limits, reward
from garage_exp.search.objectives import gym_objectives

# Plain bounds of the observation's state entries (time, speeds, distances): wide enough for any garage.
FAR = 500.0
YAW_STEP = 2.0  # degrees between the headings a moved yaw's range is checked at
EXPORTED = 6  # decimals of a moved value: the actors stand where an exported scenario, rerun, puts them


def job_config(cfg: DictConfig) -> DictConfig:
    """The experiment's part of a gym config (what a job of `python -m garage_exp` would take)."""
    keys = [k for k in cfg if k not in ("gym", "mode", "hydra")]
    return OmegaConf.masked_copy(cfg, keys)


def compose(overrides: list[str] | tuple[str, ...] = ()) -> DictConfig:
    """The gym config as `python -m garage_exp.gym OVERRIDES` composes it (for gymnasium.make)."""
    from garage_exp.core.shell import compose as compose_config
    from garage_exp.gym import schema

    return compose_config("gym", overrides, schemas=(schema.register,))


class StepOutEnv(gymnasium.Env):
    """A sequential adversary's environment on one case (`cfg`: a composed gym config, or `overrides` to compose
    one). Construction checks everything and builds the scene: GarageError on bad input."""

    metadata = {"render_modes": []}

    def __init__(self, cfg: DictConfig | None = None, overrides: list[str] | tuple[str, ...] = ()):
        from garage_exp.run.preflight import preflight
        from garage_exp.scenario.build import EGO, MOVABLE, frame_values
        from garage_exp.scenario.live import LiveScenario

        super().__init__()
        self.cfg = cfg if cfg is not None else compose(overrides)
        self.job = job = job_config(self.cfg)  # the node: preflight checks it, an export writes it
        self.ego = settings(job.ego)  # what the stages below are handed: plain data
        reward.check_ego(self.ego)
        case = job.case
        if str(case.motion.actor) != EGO:
            raise GarageError(f"the environment drives the ego by the case's motion; case {case.name!r} moves "
                              f"{case.motion.actor or 'nothing'!r} (use case=stepout or case=pullout)",
                              "case.motion.actor")
        prepared = preflight(job, check_space=False)
        self.scene, self.setup = prepared.scene, prepared.setup
        self.checked_detector = prepared.detector  # every entry loaded by the preflight (perception.detect)
        self.job_spec = prepared.spec  # (gymnasium's `spec` is the env's registration)
        self.search = settings(job.search)
        self.live = LiveScenario(self.job_spec.scene, prepared.classified, self.setup, int(self.cfg.gym.variant))
        ego_conf = self.live.actors[EGO]
        self.drive = [float(v) for v in frame_values(self.job_spec.scene.case, ego_conf, self.live.site,
                                                     self.live.made[EGO].extent[0], self.live.bays)]
        if len(self.drive) < 2:
            raise GarageError("the ego's motion has a single frame: nothing to drive", "case.motion")
        self.step_m = abs(self.drive[1] - self.drive[0])
        self.dt = self.step_m / (float(job.ego.speed) / 3.6)
        self.drive_key = str(case.motion.key)
        self.movers = limits.resolve_movers(self.cfg.gym.movers, self.live.actors, MOVABLE)
        self._check_reach()
        self.critical = reward.critical(self.ego)
        self.objective = str(self.cfg.gym.objective)
        # The episode's verdict each objective rewards, by the gym's name (search/objectives.py: seen too late to
        # stop, or hard over its fair frames), read from the registry when the env is made.
        if self.objective not in gym_objectives():
            raise GarageError(f"unknown objective {self.objective!r} ({' | '.join(gym_objectives())})",
                              "gym.objective")
        self.shaping = float(self.cfg.gym.shaping)
        self.stop_when_decided = bool(self.cfg.gym.stop_when_decided)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(len(self.movers),), dtype=np.float32)
        t_end = self.dt * len(self.drive)
        low = [0.0, 0.0, -FAR, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        high = [t_end, FAR, FAR, FAR, FAR, 1.0, 1.0, 1.0, 1.0]
        for m in self.movers:
            low += [m.low, -m.rate]
            high += [m.high, m.rate]
        self.observation_space = spaces.Box(np.array(low, dtype=np.float32), np.array(high, dtype=np.float32),
                                            dtype=np.float32)
        self.renderer = self.detector = self.sensor = self.pipeline = None
        self.renders = 0  # frames rendered and detected by this environment, all episodes
        self.k = 0
        self._state_reset()

    # -- the warm renderer and detector of the process ------------------------------------------------------------

    def _open(self) -> None:
        from garage_exp.core.plugins import build
        from garage_exp.perception.detect.worker import open_detector
        from garage_exp.render.open import open_renderer
        from garage_exp.scenario.assemble import HIDDEN
        from garage_exp.scene.views import picture_lens

        job = self.job
        if self.detector is None or (hasattr(self.detector, "alive") and not self.detector.alive()):
            self.detector = open_detector(self.checked_detector, picture_lens(self.scene.cameras[0]))
        if self.sensor is None:
            self.sensor = build(job.sensor, "a sensor model", "sensor._target_")
        if self.renderer is None:  # the job's render scene, opened as a job opens it (its forks share it)
            self.renderer = open_renderer(self.job_spec.renderer, HIDDEN)
        if self.renderer.description is not self.scene:  # another env's scene was loaded since
            self.renderer.load(self.scene)

    # -- the episode ----------------------------------------------------------------------------------------------

    def _state_reset(self) -> None:
        self.k = 0
        self.values = {m.name: m.start for m in self.movers}
        self.velocity = {m.name: 0.0 for m in self.movers}
        self.frames: list[dict] = []
        self.hits: list[bool] = []
        self.confirmed = False
        self.fair_before = False
        self.last = {"composite": 0.0, "range": FAR}
        self.ret = 0.0
        self.started = time.perf_counter()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._open()
        self._state_reset()
        # The sensor's noise as a job draws it (run/pipeline.py: seed + 1, frame after frame), so that an exported
        # episode, rerun as a job, sees the same noisy frames and comes to its own verdict.
        self.sensor_rng = np.random.default_rng(int(self.job.seed) + 1)
        self.pipeline = None  # the frame pipeline over this episode's renderer, detector and sensor stream
        ego_pose, poses = self._poses(self.drive[0])
        self.last["range"] = self._range(ego_pose, poses)
        return self._observation(), {}

    def step(self, action):
        self.move(action)
        (row,) = shoot([self])  # a batch of one (the vector env, vector.py, shoots K episodes' frames at once)
        return self.finish(row)

    def finish(self, row: dict):
        """The step's end once its frame is judged (`row`, from `shoot`): (observation, reward, terminated,
        truncated, info), the episode's verdict in the info of its last step."""
        self.frames.append(row)
        self.hits.append(row["detected"])
        before = row["range"] > self.critical
        if row["fair"] and before:
            self.fair_before = True
        if not self.confirmed and reward.confirmed_now(self.hits, self.ego):
            self.confirmed = True
        # The dense term counts the fair frames the objective judges: before the critical distance for `late`.
        goal = gym_objectives()[self.objective]
        counted = row["fair"] and (before or not goal.until_critical)
        r = self.shaping * (1.0 - row["composite"]) if counted else 0.0
        decided = goal.until_critical and (self.confirmed or not before)
        terminated = self.k >= len(self.drive) - 1 or (self.stop_when_decided and decided)
        info = {"frame": row}
        if terminated:
            verdict = self.verdict()
            r += 1.0 if verdict[goal.verdict] else 0.0
            verdict["return"] = self.ret + r
            info["episode_verdict"] = verdict
        self.ret += r
        self.last = row
        return self._observation(), float(r), bool(terminated), False, info

    def fork(self) -> StepOutEnv:
        """Another episode in this environment's world: the same scene, scenario, movers and limits, renderer and
        detector (shared: a step never changes them), its own episode state and sensor stream. The vector env
        (vector.py) keeps K forks of one environment: one preflight, one scene in the process's renderer."""
        self._open()  # opened once, here: each fork reopening would reload the detector (and drain its queue)
        twin = copy.copy(self)
        twin.pipeline, twin.renders = None, 0
        twin._state_reset()
        return twin

    def move(self, action) -> None:
        """The step's moves, before its frame: the next frame of the drive, and each mover's value as the action
        asks, within its limits (limits.py)."""
        action = np.asarray(action, dtype=float).reshape(-1)
        self.k += 1
        for i, m in enumerate(self.movers):
            if m.once:
                if self.k == 1:
                    self.values[m.name] = round(limits.placed_once(m, action[i]), EXPORTED)
            else:
                value, self.velocity[m.name] = limits.advance(m, self.values[m.name], self.velocity[m.name],
                                                              action[i], self.dt)
                self.values[m.name] = round(value, EXPORTED)

    def _poses(self, drive: float, moved: dict[str, float] | None = None):
        """(the ego's pose, the others') with the ego at `drive` and the movers at `moved` (default: this step's)."""
        from garage_exp.scenario.build import EGO

        moved = self.values if moved is None else moved
        values: dict[str, dict[str, float]] = {EGO: {self.drive_key: drive}}
        for m in self.movers:
            values.setdefault(m.actor, {})[m.key] = moved[m.name]
        return self.live.poses(values)

    def _check_reach(self) -> None:
        """Each mover's bounds, before any episode: its actor can stand at a bound given (a car's `gap` within its
        pull-out limit, scenario/place.py), else GarageError naming `gym.movers.K.low` or `.high`; then the
        bounds are held to the job's rule of what may stand (limits.fit_bounds): no value the action space can
        reach puts two actors in one another in any frame of the drive, so every episode reruns as a job."""
        start = {m.name: m.start for m in self.movers}
        for k, m in enumerate(self.movers):
            for bound in ("low", "high"):
                if bound in m.open:
                    continue
                try:
                    self._poses(self.drive[0], {**start, m.name: getattr(m, bound)})
                except GarageError as exc:
                    raise GarageError(f"{m.name} cannot be {getattr(m, bound):g} ({exc})",
                                      f"gym.movers.{k}.{bound}") from None
        self.movers = limits.fit_bounds(self.movers, self._clash_in)

    def _clash_in(self, box: dict[str, tuple[float, float]]) -> str:
        """Which two actors some values in `box` (mover name -> (lo, hi)) put in one another, in which frame of
        the drive ('' when none): place.sweep_clash over the box's corners (a yaw's range sampled every
        YAW_STEP degrees); a value that cannot be placed at all counts as a clash."""
        from itertools import product

        from garage_exp.scenario.build import EGO
        from garage_exp.scenario.place import sweep_clash

        axes = []
        for m in self.movers:
            lo, hi = box[m.name]
            n = int(math.ceil((hi - lo) / YAW_STEP)) + 1 if m.key == "yaw" else 2
            axes.append(sorted(set(np.linspace(lo, hi, max(n, 2)).tolist())))
        corners = [dict(zip(box, values)) for values in product(*axes)]
        moved = {m.actor for m in self.movers}
        for drive in self.drive:
            try:
                frames = [self._poses(drive, c) for c in corners]
            except GarageError as exc:
                return f"an actor where it cannot stand ({exc})"
            poses = [{EGO: ego, **others} for ego, others in frames]
            varying = {n for n, p in poses[0].items() if any(f[n] != p for f in poses[1:])}
            pair = sweep_clash(poses, self.live.made, only=(moved | varying) if len(poses) > 1 else None)
            if pair:
                return f"{pair[0]} and {pair[1]} in one another (the ego's {self.drive_key} {drive:g})"
        return ""

    def _range(self, ego_pose, poses) -> float:
        """Camera to the target's centre (m), from the poses alone (ground truth's `distance`, also unrendered)."""
        from garage_exp.scene.camera import camera_to_world

        cam = self.scene.cameras[0]
        position = camera_to_world(ego_pose, cam)[:3, 3]
        target = poses[self.live.target]
        height = self.live.made[self.live.target].extent[2]
        return float(np.linalg.norm(position - np.array([target.x, target.y, height / 2])))

    def shot(self):
        """This step's shot (`scenario.Shot`): the ego at this step's point of the drive, the movers at their values."""
        from garage_exp.scenario import Shot

        ego_pose, poses = self._poses(self.drive[self.k])
        return Shot(self.k, "", 0.0, ego_pose, poses, self.live.target)

    def frame_pipeline(self):
        """The frame pipeline (run.pipeline) over this episode's renderer, detector and sensor stream."""
        from garage_exp.run.pipeline import FramePipeline

        if self.pipeline is None or self.pipeline.renderer is not self.renderer:
            spec = self.job_spec
            self.pipeline = FramePipeline(spec.frames, self.scene, self.renderer, self.sensor, self.sensor_rng,
                                          self.detector, self.checked_detector.scoring(), spec.scoring)
        return self.pipeline

    def row(self, item, score) -> dict:
        """This step's frame table row and its verdicts, from its rendered frame and the target's score."""
        self.renders += 1
        target = item.target
        row = {"frame": self.k, "time": round(self.k * self.dt, 6), "ego": self.drive[self.k],
               **{m.name: round(self.values[m.name], 6) for m in self.movers},
               "range": self._range(item.shot.ego, item.shot.poses), **reward.measured(target, score)}
        row["fair"] = reward.fair(row, self.search)
        return row

    def _observation(self) -> np.ndarray:
        n = int(self.ego.n)
        window = self.hits[-n:]
        obs = [self.k * self.dt, float(self.ego.speed) / 3.6, self.drive[self.k], self.critical,
               min(self.last["range"], FAR), self.last["composite"], sum(window) / n, float(self.confirmed),
               float(self.fair_before)]
        for m in self.movers:
            obs += [self.values[m.name], self.velocity[m.name]]
        box = self.observation_space
        return np.clip(np.array(obs, dtype=np.float32), box.low, box.high)

    def verdict(self) -> dict:
        """The episode so far, judged: late (the reward's), testable, detection distance, fair difficulty, the
        moved values per frame, renders and wall time."""
        record = reward.episode(self.frames, self.ego, [m.name for m in self.movers], self.critical,
                                time.perf_counter() - self.started)
        record["params"] = limits.summary(self.movers, record["values"], self.dt, self.drive)
        record["variant"] = int(self.cfg.gym.variant)
        return record

    def close(self) -> None:
        # The renderer and the detector child belong to the process (core.state.STATE): later envs and jobs reuse them.
        self.renderer = self.detector = self.pipeline = None


def shoot(envs: list[StepOutEnv]) -> list[dict]:
    """The frames of `envs`' current steps (after `move`): the ego's first camera rendered, detected and the
    target scored, as ONE batch through the frame pipeline of the first env (the envs are forks of one world,
    `StepOutEnv.fork`: one scene, renderer and detector), each env's camera model drawing from its own sensor
    stream; their rows, env by env. A lone env's step is a batch of one."""
    from garage_exp.run.pipeline import in_view

    if not envs:
        return []
    world = envs[0]
    if any(env.scene is not world.scene for env in envs):
        raise ValueError("one batch of frames is one world's: the envs must be forks of one environment")
    pipeline = world.frame_pipeline()
    shots = [env.shot() for env in envs]
    # Only the case's actors are in view (parked cars are scenery here: a step renders no silhouette of them).
    actors = [in_view(world.scene, s.poses, placed_only=True) for s in shots]
    done = pipeline.detect_shots(shots, world.scene.cameras[0].name, actors, [env.sensor_rng for env in envs])
    return [env.row(item, pipeline.score(item, dets)) for env, (item, dets) in zip(envs, done)]


# `garage_exp/PullOut-v0`: case=pullout with the car's `gap` as the adversary's one mover, from parked (0.2 m behind
# the bay line, the case's own) to 1.8 m into the lane (short of the ego's path on every shipped plan), at a car's
# pull-out limits (limits.py: 2 m/s, 2 m/s^2). The same from the command line:
#   python -m garage_exp.gym case=pullout 'gym.movers=[{actor: car, key: gap, low: -1.8, high: 0.2}]'
PULLOUT = ("case=pullout", "gym.movers=[{actor: car, key: gap, low: -1.8, high: 0.2}]")


class PullOutEnv(StepOutEnv):
    """The adversary times a car pulling out of its bay nose first (case=pullout): each step's action is the
    car's `gap` velocity (-1: out at the top speed, towards the ego's path; +1: back into the bay). `overrides` come
    after the preset (PULLOUT); a `cfg` is taken as it is (compose(PULLOUT + ...) makes one)."""

    def __init__(self, cfg: DictConfig | None = None, overrides: list[str] | tuple[str, ...] = ()):
        super().__init__(cfg if cfg is not None else compose([*PULLOUT, *overrides]))
