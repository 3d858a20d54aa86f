"""Replaying an export in esmini (the open-source OpenSCENARIO player) and reading back where it put everything:
the judge of whether a file plays as the job ran (tests/test_esmini.py, docs/openscenario.md's replay figure).

esmini is found as the vehicle models are (assets/locate.py): $GARAGE_EXP_ESMINI (the binary), else
`../shared/tools/esmini/esmini`. It runs headless at a fixed step and writes a csv log of every entity's pose,
road, lane and collisions per step; `--collision` makes it report touching bounding boxes.
"""

from __future__ import annotations

import csv
import math
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from garage_exp.core import paths
from garage_exp.core.errors import GarageError

ESMINI_ENV = "GARAGE_EXP_ESMINI"
STEP = 0.05  # s: esmini's fixed time step here


def esmini_path() -> Path:
    """The esmini binary; GarageError saying where it was looked for when there is none."""
    env = os.environ.get(ESMINI_ENV)
    candidates = [Path(env).expanduser()] if env else [paths.shared_dir() / "tools" / "esmini" / "esmini"]
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return path
    where = f"{ESMINI_ENV}={env}" if env else str(candidates[0])
    raise GarageError("no esmini binary (tools/esmini/README.md in ../shared says how it is built)", where)


@dataclass
class Sample:
    """One entity at one step, as esmini's csv log has it: the reference point (x, y), heading (radians), the
    bounding box's centre relative to the reference point, the road, lane and lateral offset it is on."""

    t: float
    x: float
    y: float
    h: float
    bb_x: float
    bb_y: float
    road_s: float
    lane: int
    lane_offset: float
    heading_to_drive: float  # heading relative to its lane's driving direction (radians)
    collisions: str

    def centre(self) -> tuple[float, float]:
        """The bounding box's centre on the ground (garage_exp's pose of an actor)."""
        c, s = math.cos(self.h), math.sin(self.h)
        return self.x + c * self.bb_x - s * self.bb_y, self.y + s * self.bb_x + c * self.bb_y


@dataclass
class Replay:
    """What one esmini run logged: each entity's samples in time order, and what it said."""

    samples: dict[str, list[Sample]] = field(default_factory=dict)
    output: str = ""

    def at(self, name: str, t: float) -> tuple[float, float, float]:
        """The entity's bounding-box centre and heading (degrees) at time t, linear between logged steps."""
        rows = self.samples[name]
        k = min(max(int(math.floor(t / STEP + 1e-6)), 0), len(rows) - 1)
        a = rows[k]
        b = rows[min(k + 1, len(rows) - 1)]
        w = 0.0 if b.t <= a.t else min(max((t - a.t) / (b.t - a.t), 0.0), 1.0)
        (ax, ay), (bx, by) = a.centre(), b.centre()
        dh = (b.h - a.h + math.pi) % (2 * math.pi) - math.pi
        return ax + w * (bx - ax), ay + w * (by - ay), math.degrees(a.h + w * dh)

    def collided(self) -> set[frozenset[str]]:
        """The pairs of entities esmini reported touching at any step."""
        pairs = set()
        for name, rows in self.samples.items():
            for row in rows:
                for other in row.collisions.split():
                    pairs.add(frozenset((name, self._names_by_id.get(other, other))))
        return pairs

    _names_by_id: dict[str, str] = field(default_factory=dict)


def play(xosc: Path, workdir: Path, collision: bool = True, timeout: float = 120.0) -> Replay:
    """Run esmini headless on `xosc` at the fixed step; its log read back (`workdir`/log.csv)."""
    workdir.mkdir(parents=True, exist_ok=True)
    log = workdir / "log.csv"
    cmd = [str(esmini_path()), "--headless", "--osc", str(Path(xosc).resolve()), "--fixed_timestep", str(STEP),
           "--csv_logger", str(log), "--logfile_path", str(workdir / "esmini.txt")]
    if collision:
        cmd.append("--collision")
    done = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0 or not log.is_file():
        raise GarageError(f"esmini exited {done.returncode}: {(done.stderr or done.stdout).strip()[-300:]}",
                          str(xosc))
    replay = read_log(log)
    replay.output = done.stdout + done.stderr
    return replay


def read_log(log: Path) -> Replay:
    """esmini's csv log (--csv_logger): a header, then one row per step with a block of columns per entity."""
    replay = Replay()
    with log.open(newline="") as f:
        for row in csv.reader(f):
            if len(row) < 3 or not row[0].strip().isdigit():
                continue
            t = float(row[1])
            cells = [c.strip() for c in row[2:]]
            width = 31  # columns per entity in esmini 3.6's log
            for k in range(0, len(cells) - width + 1, width):
                block = cells[k:k + width]
                name = block[0]
                replay._names_by_id[block[1]] = name
                replay.samples.setdefault(name, []).append(Sample(
                    t=t, x=float(block[11]), y=float(block[12]), h=float(block[24]), bb_x=float(block[5]),
                    bb_y=float(block[6]), road_s=float(block[20]), lane=int(float(block[22])),
                    lane_offset=float(block[23]), heading_to_drive=float(block[27]), collisions=block[30]))
    return replay


def draw_replays(classified, shots, clock: list[float], panels: list[tuple[str, Replay]], path: Path,
                 names: list[str] | None = None) -> Path:
    """A PNG of the job's trajectories (each actor's pose at each frame: dots) and esmini's (its log: lines) on
    the plan, one panel per replay (title, Replay), cropped to where the actors are."""
    from collections import Counter

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from garage_exp.plan.draw import _draw_cells, _draw_pillars

    names = names or ["ego", *[n for n in shots[0].poses if shots[0].poses[n] is not None]]
    job = {n: [(s.ego if n == "ego" else s.poses[n]) for s in shots] for n in names}
    xs = [p.x for ps in job.values() for p in ps]
    ys = [p.y for ps in job.values() for p in ps]
    box = (min(xs) - 4, max(xs) + 4, min(ys) - 4, max(ys) + 4)
    fig = Figure(figsize=(5.2 * len(panels), 5.2 * (box[3] - box[2]) / (box[1] - box[0]) + 1.4), dpi=110)
    FigureCanvasAgg(fig)
    colours = ["#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2"]
    for k, (title, replay) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), k + 1)
        _draw_cells(ax, classified, Counter())
        _draw_pillars(ax, classified, 0.6)
        for n, colour in zip(names, colours):
            if n in replay.samples:
                pts = [replay.at(n, r.t)[:2] for r in replay.samples[n] if r.t <= clock[-1] + 1e-6]
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "-", color=colour, lw=3, alpha=0.6, zorder=3,
                        label=f"{n}: esmini")
                ax.plot(*pts[0], "+", color=colour, ms=12, mew=2, zorder=5)  # where esmini starts it
            ax.plot([p.x for p in job[n]], [p.y for p in job[n]], "o", color=colour, ms=3.5, mfc="white",
                    zorder=4, label=f"{n}: the job's frames")
        ax.set_xlim(box[0], box[1])
        ax.set_ylim(box[2], box[3])
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("x (m)", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.legend(*ax.get_legend_handles_labels(), fontsize=7, loc="lower center", ncol=len(names), frameon=False)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path
