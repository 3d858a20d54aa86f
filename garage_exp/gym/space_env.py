"""The gym on a shipped space (`python -m garage_exp.gym space=wide gym.objective=hard`): one-shot scenarios whose
every factor is the adversary's action.

`space=NAME` (conf/space/NAME.yaml) names the factors the search draws (search/space.py: `expand` puts the space's
`params` before the command's overrides, a key the command sets itself keeps the command's value and is no factor;
`settle` gives the space's `require:` to `search.require`). Here each searched factor is one dimension of a Box
action in [-1, 1] (`decode`: an interval's range, on its log axis for a log range, an integer one rounded to its
step, a choice's levels in equal bins), so the action space has exactly the space's factors and
stable-baselines3's PPO takes it as any Box. The fixed entries (`plan=generated`, `camera.mount=bumper`) and the
space's case (its defaults list's: `oneshot`; a `case=...` on the command line wins) are composed once.

An episode is one scenario: `reset` shows nothing (a one-shot scenario has no state before it is drawn: the
observation is a constant), `step(action)` draws it and ends the episode. Each draw is checked as a search's trial
(run/preflight.py: the scene description), then by the space's requirements from geometry before any pixel is
rendered (search/require.py). The search redraws a rejected draw; a policy's action is its own choice, so
redrawing it at random would credit the policy with a draw it did not make. A rejected draw (or one whose actors
stand in one another) therefore ends its episode unrendered with reward 0, the same as a scenario with no fair frame:
nothing a policy can earn there, so it learns to avoid the region, as the search's samplers learn from a PRUNED
trial; `info["rejected"]` says why and `rejected` counts them (the acceptance rate). A rendered draw earns the
objective's verdict: `hard` (1 when its difficulty over the fair frames, 1 - the detectors' mean confidence, is at
least 0.6) plus `gym.shaping` x its difficulty. `late` needs an approach to be late on, which a one-shot scenario
has not: refused.

What the gym cannot take, refused in one line (exit 2): a factor that is a config group's level (`light=choice(dim,
bright)`: each draw would compose a new config; the search takes it), and `gym.envs` > 1 (the vector env steps
forks of one world; a space draws a new one every step).
"""

from __future__ import annotations

import copy
import math
import shlex

import gymnasium
import numpy as np
import optuna.distributions as od
from gymnasium import spaces
from omegaconf import DictConfig, OmegaConf

from garage_exp.core.errors import GarageError, Infeasible
from garage_exp.core.plain import settings
from garage_exp.gym import reward
from garage_exp.search import space as space_mod
from garage_exp.search.objectives import gym_objectives


def group_levels() -> dict[str, list[str]]:
    """Each config group of the project's conf/ and its levels (what `space_mod.build` checks choices against)."""
    from garage_exp.core.shell import CONF_DIR

    return {d.name: sorted(f.stem for f in d.glob("*.yaml")) for d in CONF_DIR.iterdir()
            if d.is_dir() and d.name != "hydra"}


def space_case(cfg: DictConfig) -> str | None:
    """The case the space's file picks in its defaults list (`override /case@_global_.case: oneshot`), if any."""
    from pathlib import Path

    from garage_exp.core.shell import CONF_DIR

    path = Path(CONF_DIR) / "space" / f"{cfg.space.name}.yaml"
    if not path.is_file():
        return None
    for entry in OmegaConf.load(path).get("defaults") or []:
        if isinstance(entry, DictConfig):
            for key, value in entry.items():
                if str(key).split("@")[0].replace("override", "").strip().strip("/") == "case":
                    return str(value)
    return None


def decode(action, params: dict[str, od.BaseDistribution]) -> dict:
    """An action in [-1, 1]^D as the space's values, factor by factor (module doc)."""
    out = {}
    for a, (name, dist) in zip(np.clip(np.asarray(action, dtype=float).reshape(-1), -1.0, 1.0), params.items()):
        u = (float(a) + 1.0) / 2.0  # 0..1
        if isinstance(dist, od.CategoricalDistribution):
            out[name] = dist.choices[min(int(u * len(dist.choices)), len(dist.choices) - 1)]
            continue
        low, high = float(dist.low), float(dist.high)
        if getattr(dist, "log", False):
            value = math.exp(math.log(low) + u * (math.log(high) - math.log(low)))
        else:
            value = low + u * (high - low)
        if isinstance(dist, od.IntDistribution):
            step = dist.step or 1
            value = int(min(max(dist.low + round((value - dist.low) / step) * step, dist.low), dist.high))
        out[name] = value
    return out


class SpaceEnv(gymnasium.Env):
    """One-shot scenarios of a shipped space, the action its factors (module doc). `cfg`: the gym config as the
    command composed it, with `arguments` the command's overrides (which keys it sets itself); or `overrides` alone,
    composed here. Construction checks the space and loads the detector: GarageError on bad input."""

    metadata = {"render_modes": []}

    def __init__(self, cfg: DictConfig | None = None, overrides: list[str] | tuple[str, ...] = ()):
        from garage_exp.gym.env import compose

        super().__init__()
        arguments = [str(a) for a in overrides]
        given = compose(arguments) if cfg is None else cfg
        if not OmegaConf.select(given, "space.params", default=None):
            raise GarageError(f"space {given.space.name!r} has no factors (params) to draw", "space")
        goal = gym_objectives().get(str(given.gym.objective))
        if goal is not None and goal.until_critical:
            raise GarageError(f"a one-shot scenario of space {given.space.name!r} has no approach to be "
                              f"{given.gym.objective} on: give gym.objective=hard", "gym.objective")
        if int(given.gym.envs) != 1:
            raise GarageError("a space draws a new scene every step; the vector env steps forks of one: gym.envs=1",
                              "gym.envs")
        expanded = space_mod.expand(given, arguments)
        case = space_case(given)
        fixed_lines = [o.input_line for o in space_mod.parse(expanded) if not o.is_sweep_override()]
        if case and not any(line.split("=", 1)[0].lstrip("+~") == "case" for line in fixed_lines):
            fixed_lines.insert(0, f"case={case}")
        try:
            self.base = compose(fixed_lines)  # the space's fixed entries and case, then the command's
        except GarageError:
            raise
        except Exception as exc:  # Hydra's own refusal of a fixed entry (a level its group lacks, a bad value)
            raise space_mod.in_space_file(GarageError(str(exc).splitlines()[0], "search space"), given) from None
        groups = group_levels()
        try:
            self.space = space_mod.build(expanded, self.base, groups)
        except GarageError as exc:
            raise space_mod.in_space_file(exc, given) from None
        for name, written in self.space.written.items():
            if name in groups:
                raise space_mod.in_space_file(GarageError(
                    f"{name} is a config group: the gym draws values on one composed config (fix its level, or "
                    "search it: python -m garage_exp -m hydra/sweeper=search)", f"search space {written}"), given)
        space_mod.settle(self.base, expanded)  # the space's requirements onto search.require
        from garage_exp.search.require import Require, check_require

        check_require(self.base.search.require)
        self.require = Require.of(self.base.search.require)
        self.cfg = self.base
        self.params = self.space.params
        self.objective = str(given.gym.objective)
        self.shaping = float(given.gym.shaping)
        self.search = settings(self.base.search)
        self.movers: list = []  # the step-out env's; a space's factors are its action
        self.action_space = spaces.Box(-1.0, 1.0, shape=(len(self.params),), dtype=np.float32)
        self.observation_space = spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)
        self.renders = self.draws = self.rejected = 0
        self.job = self.detector = None  # the last draw's job config; the detector child
        self._lines = {}  # override line -> parsed override (a choice's levels recur)
        self.prepare(space_mod.middle_point(self.space))  # the middle's job: the detector loads (or is refused) now

    # -- a draw -----------------------------------------------------------------------------------------------------

    def overrides(self, values: dict) -> list[str]:
        """A draw's searched values as override lines (a rerun: `python -m garage_exp space=NAME <these>`)."""
        return [f"{name}={space_mod.format_value(values[name])}" for name in self.params]

    def draw_config(self, values: dict) -> DictConfig:
        """The job config of one draw: the composed base with its values set, as the search's launcher sets a
        trial's (search/launch.py: CachedLaunch.compose)."""
        from hydra.core.override_parser.overrides_parser import OverridesParser

        from garage_exp.gym.env import job_config

        cfg = copy.deepcopy(self.base)
        for line in self.overrides(values):
            if line not in self._lines:
                self._lines[line] = OverridesParser.create().parse_overrides([line])[0]
            o = self._lines[line]
            OmegaConf.update(cfg, o.key_or_group, o.value(), merge=True)
        return job_config(cfg)

    def prepare(self, values: dict):
        """The draw's checked job (run/preflight.py, the detector loaded); Infeasible when its actors stand in one
        another."""
        from garage_exp.run.preflight import preflight

        job = self.draw_config(values)
        try:
            prepared = preflight(job, check_space=False)
        except Infeasible:
            return job, None
        self.detector = prepared.opened  # the process's detector child (train.py counts its CPU time)
        return job, prepared

    # -- the episode ------------------------------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action):
        from garage_exp.search.require import judge

        values = decode(action, self.params)
        self.draws += 1
        self.job, prepared = self.prepare(values)
        why = "" if prepared is not None else "infeasible: two actors stand in one another"
        if prepared is not None and self.require is not None:
            verdict = judge(self.require, prepared.scene, prepared.setup, prepared.spec.primary)
            why = "" if verdict.ok else verdict.why
        rows = self.shoot(prepared) if not why else []
        if why:
            self.rejected += 1
        record = self.verdict(values, rows, why)
        r = (self.shaping * record["difficulty"] + float(record[self.goal()])) if record["fair_frames"] else 0.0
        record["return"] = r
        info = {"episode_verdict": record, "frames": rows}
        if why:
            info["rejected"] = why
        return np.zeros(1, dtype=np.float32), float(r), True, False, info

    def goal(self) -> str:
        """The record's key the objective rewards (`hard_fair` for hard)."""
        return gym_objectives()[self.objective].verdict

    def shoot(self, prepared) -> list[dict]:
        """The draw's shots rendered through the job's frame pipeline, detected and scored: a frame row each."""
        from garage_exp.core.plugins import build
        from garage_exp.render.open import open_renderer
        from garage_exp.run.pipeline import FramePipeline, in_view
        from garage_exp.scenario.assemble import HIDDEN

        scene, setup, spec = prepared.scene, prepared.setup, prepared.spec
        if getattr(self, "renderer", None) is None:  # the job's render scene, opened as a job opens it, kept
            self.renderer = open_renderer(spec.renderer, HIDDEN)
        renderer = self.renderer
        if renderer.description is not scene:
            renderer.load(scene)
        sensor = build(self.job.sensor, "a sensor model", "sensor._target_")
        rng = np.random.default_rng(int(self.job.seed) + 1)  # the sensor's stream as a job draws it
        pipeline = FramePipeline(spec.frames, scene, renderer, sensor, rng, prepared.opened,
                                 prepared.detector.scoring(), spec.scoring)
        shots = list(setup.shots)
        actors = [in_view(scene, s.poses, placed_only=True) for s in shots]
        rows = []
        for item, dets in pipeline.detect_shots(shots, spec.primary, actors, [rng] * len(shots)):
            row = {"frame": len(rows), **reward.measured(item.target, pipeline.score(item, dets))}
            row["fair"] = reward.fair(row, self.search)
            rows.append(row)
        self.renders += len(rows)
        return rows

    def verdict(self, values: dict, rows: list[dict], rejected: str) -> dict:
        """The episode (one draw) judged: its fair difficulty, hard_fair, the drawn values (`params`) and the
        rerun's overrides."""
        fair = [r["composite"] for r in rows if r["fair"]]
        # None, not NaN, without a fair frame: NaN != NaN, and the same action must give the same info
        difficulty = float(1.0 - np.mean(fair)) if fair else None
        return {"late": False, "testable": bool(fair), "fair_frames": len(fair), "difficulty": difficulty,
                "hard_fair": bool(fair and difficulty >= reward.HARD), "renders": len(rows),
                "rejected": rejected,  # no wall time: a step's info is the same for the same action (env checker)
                "params": {k: (v if isinstance(v, (int, float)) else str(v)) for k, v in values.items()},
                "overrides": self.overrides(values)}

    def write_suite(self, records: list[dict], root, per_band: int) -> list:
        """The episodes as a manifest of scenarios (band, difficulty, the rerun command), K per band over the
        fairly visible ones (search/suite.py's bands)."""
        from pathlib import Path

        import pandas as pd

        from garage_exp.search.suite import DEFAULT_BANDS, band_of

        root = Path(root)
        root.mkdir(parents=True, exist_ok=True)
        rows, count = [], {}
        for k, r in enumerate(records):
            if not r["fair_frames"]:
                continue
            band = band_of(1.0 - r["difficulty"], DEFAULT_BANDS)
            if band is None or count.get(band, 0) >= per_band:
                continue
            count[band] = count.get(band, 0) + 1
            rows.append({"scenario": f"{band}_{count[band]}", "band": band, "difficulty": r["difficulty"],
                         "episode": k, "command": shlex.join(["python", "-m", "garage_exp", *self.rerun_fixed(),
                                                               *r["overrides"]])})
        path = root / "manifest.csv"
        pd.DataFrame(rows, columns=["scenario", "band", "difficulty", "episode", "command"]).to_csv(path, index=False)
        return [path]

    def rerun_fixed(self) -> list[str]:
        """What a job needs besides a draw's values to rerun it: the space (its case) and its fixed entries, less
        the gym's own keys."""
        own = ("gym", "mode", "space", "hydra")
        kept = [line for line in self.space.fixed if line.split("=", 1)[0].lstrip("+~").split(".")[0] not in own]
        return [f"space={self.base.space.name}", *kept]

    def close(self) -> None:  # the renderer and the detector child are the process's (core.state.STATE)
        self.renderer = None
