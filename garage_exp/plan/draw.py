"""Top-down map of a classified plan: cells to scale in world metres, coloured by type, with each cell's
rotation, the pillars and the perimeter walls. Uses matplotlib's Agg canvas directly (no pyplot), so drawing
never touches a display or global matplotlib state."""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import Patch, Rectangle

from garage_exp.core.errors import GarageError
from garage_exp.plan.classify import Cell, Classified

PILLAR_SIZE = 0.6  # metres per side; the default of GarageConf.pillar_size
# Beyond this many cells the arrows are sub-pixel clutter and cost seconds to draw.
MAX_ARROW_CELLS = 4000

# (kind, type) -> (legend label, face colour, hatch). Lanes in cool tones (darker = more branches), bays in
# warm tones (darker = more lane sides), ramps green and magenta, so the drivable network stands out from
# the bays at a glance.
STYLE: dict[tuple[str, str], tuple[str, str, str]] = {
    ("lane", "straight"): ("lane: straight", "#c6dbef", ""),
    ("lane", "corner"): ("lane: corner", "#b9b0dc", ""),
    ("lane", "t_junction"): ("lane: T-junction", "#6baed6", ""),
    ("lane", "crossroads"): ("lane: crossroads", "#3a7fc0", ""),
    ("parking", "type1"): ("parking: Type1 (2 opposite / 3+ lanes)", "#e6550d", ""),
    ("parking", "type2"): ("parking: Type2 (2 adjacent lanes)", "#fd8d3c", ""),
    ("parking", "type3"): ("parking: Type3 (1 lane)", "#fdd49e", ""),
    ("parking", "type4"): ("parking: Type4 (no lane)", "#fff7ec", ".."),
    ("entrance", ""): ("entrance", "#31a354", ""),
    ("exit", ""): ("exit", "#e7298a", ""),
    ("obstacle", ""): ("obstacle", "#8c8c8c", "xx"),
}
PILLAR_COLOUR = "#1a1a1a"
WALL_COLOUR = "#404040"


def _style_key(cell: Cell) -> tuple[str, str]:
    # Entrances and exits are classified like lanes too; on the map their role matters more than their shape.
    if cell.kind in ("entrance", "exit", "obstacle"):
        return cell.kind, ""
    return cell.kind, cell.type


def _nice_length(span: float) -> float:
    """A round scale-bar length (1, 2 or 5 x 10^k m) close to a fifth of the span."""
    target = max(span / 5.0, 1e-9)
    base = 10 ** math.floor(math.log10(target))
    return min((k * base for k in (1, 2, 5, 10)), key=lambda v: abs(v - target))


def _perimeter_walls(classified: Classified) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """Outer edges of the border cells, left open where an entrance or exit ramp passes through the wall."""
    plan = classified.plan
    m, n = plan.shape
    segments = []
    for cell in classified.all_cells():
        if cell.kind in ("entrance", "exit"):
            continue
        x0, y0, x1, y1 = plan.cell_rect(cell.i, cell.j)
        if cell.i == 0:
            segments.append(((x0, y1), (x1, y1)))
        if cell.i == m - 1:
            segments.append(((x0, y0), (x1, y0)))
        if cell.j == 0:
            segments.append(((x0, y0), (x0, y1)))
        if cell.j == n - 1:
            segments.append(((x1, y0), (x1, y1)))
    return segments


def _draw_cells(ax, classified: Classified, counts: Counter) -> None:
    plan = classified.plan
    by_style: dict[tuple[str, str], list[Rectangle]] = {}
    for cell in classified.all_cells():
        key = _style_key(cell)
        counts[key] += 1
        x0, y0, x1, y1 = plan.cell_rect(cell.i, cell.j)
        by_style.setdefault(key, []).append(Rectangle((x0, y0), x1 - x0, y1 - y0))
    # Thin grid lines stay visible for big plans but do not eat small cells.
    edge_width = 0.6 if plan.S.size <= 400 else 0.2
    for key, rects in by_style.items():
        _, colour, hatch = STYLE[key]
        ax.add_collection(PatchCollection(rects, facecolor=colour, edgecolor="white", linewidth=edge_width,
                                          hatch=hatch or None, zorder=1))


def _draw_arrows(ax, classified: Classified) -> None:
    """Straight lanes get a double-headed arrow along their axis (they have no single direction); every
    other non-obstacle cell gets one arrow along its stored rotation."""
    plan = classified.plan
    single, double = [], []
    for cell in classified.all_cells():
        if cell.kind == "obstacle":
            continue
        cx, cy = plan.cell_center(cell.i, cell.j)
        half = 0.22 * min(float(plan.C[cell.j]), float(plan.R[cell.i]))
        ux, uy = math.cos(math.radians(cell.rotation)), math.sin(math.radians(cell.rotation))
        if cell.kind == "lane" and cell.type == "straight":
            double.append((cx, cy, ux * half, uy * half))
            double.append((cx, cy, -ux * half, -uy * half))
        else:
            single.append((cx - ux * half, cy - uy * half, 2 * ux * half, 2 * uy * half))
    width = 0.05 * float(np.median(np.minimum.outer(plan.R, plan.C)))
    common = dict(angles="xy", scale_units="xy", scale=1, units="xy", width=width, headwidth=3.5,
                  headlength=3.5, headaxislength=3.0, color="#222222", zorder=3, pivot="tail")
    for arrows in (single, double):
        if arrows:
            x, y, u, v = np.asarray(arrows).T
            ax.quiver(x, y, u, v, **common)


def _draw_pillars(ax, classified: Classified, size: float) -> None:
    plan = classified.plan
    h = size / 2
    squares = []
    for p in classified.pillars:
        x, y = plan.vertex(p.a, p.b)
        x, y = x + p.sx * h, y + p.sy * h  # the pillar's centre, shifted off the lanes
        squares.append(Rectangle((x - h, y - h), size, size))
    if squares:
        ax.add_collection(PatchCollection(squares, facecolor=PILLAR_COLOUR, edgecolor="none", zorder=4))


def _draw_scale_bar(ax, width: float, y: float) -> None:
    length = _nice_length(width)
    label = f"{length:g} m"
    ax.plot([0.0, length], [y, y], color="black", linewidth=3, solid_capstyle="butt", zorder=5, clip_on=False)
    for x in (0.0, length):
        ax.plot([x, x], [y - 0.15 * abs(y), y + 0.15 * abs(y)], color="black", linewidth=1, clip_on=False)
    ax.text(length + 0.01 * width, y, label, va="center", ha="left", fontsize=8)


def _index_axes(ax, classified: Classified) -> None:
    """Column indices along the top and row indices along the right, so a cell named in an error message
    ("S row 3, column 5") is easy to find."""
    plan = classified.plan
    m, n = plan.shape
    step_j = max(1, math.ceil(n / 40))
    step_i = max(1, math.ceil(m / 40))
    top = ax.secondary_xaxis("top")
    top.set_xticks([(plan.x_edges[j] + plan.x_edges[j + 1]) / 2 for j in range(0, n, step_j)],
                   [str(j) for j in range(0, n, step_j)])
    top.tick_params(labelsize=7, length=2)
    top.set_xlabel("column j", fontsize=8)
    right = ax.secondary_yaxis("right")
    right.set_yticks([(plan.y_edges[i] + plan.y_edges[i + 1]) / 2 for i in range(0, m, step_i)],
                     [str(i) for i in range(0, m, step_i)])
    right.tick_params(labelsize=7, length=2)
    right.set_ylabel("row i", fontsize=8)


def draw_map(classified: Classified, path: str | Path, title: str | None = None,
             pillar_size: float | None = None) -> Path:
    """Write a top-down PNG of the plan to `path` (parent folders are created) and return the path.
    `pillar_size` (m) should match the garage config so the map shows the pillars the scene will have (default:
    the plan's own, a generated plan's, else PILLAR_SIZE)."""
    plan = classified.plan
    if pillar_size is None:
        pillar_size = dict(plan.garage).get("pillar_size", PILLAR_SIZE)
    path = Path(path)
    m, n = plan.shape
    width, depth = plan.size
    # Size the figure to the garage's aspect; the legend takes a strip on the right and the tight bounding
    # box at save time trims whatever is left over, so titles and labels are never clipped.
    longest = max(width, depth)
    plan_w = max(10.0 * width / longest, 3.0)
    plan_h = max(10.0 * depth / longest, 3.0)
    fig = Figure(figsize=(plan_w + 4.0, plan_h + 1.5), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.06, 0.08, 0.68, 0.84))

    counts: Counter = Counter()
    _draw_cells(ax, classified, counts)
    ax.add_collection(LineCollection(_perimeter_walls(classified), colors=WALL_COLOUR, linewidths=2.5,
                                     zorder=2, capstyle="projecting"))
    if plan.S.size <= MAX_ARROW_CELLS:
        _draw_arrows(ax, classified)
    _draw_pillars(ax, classified, pillar_size)

    margin = 0.02 * max(width, depth)
    bar_y = -0.06 * max(width, depth)
    ax.set_xlim(-margin, width + margin)
    ax.set_ylim(bar_y - margin, depth + margin)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.tick_params(labelsize=8)
    _draw_scale_bar(ax, width, bar_y)
    _index_axes(ax, classified)
    ax.set_title(title or f"{plan.name}: {m} x {n} cells, {width:.1f} x {depth:.1f} m", fontsize=11, pad=24)

    handles = [Patch(facecolor=STYLE[k][1], edgecolor="#666666", hatch=STYLE[k][2] or None,
                     label=f"{STYLE[k][0]}  ({counts[k]})") for k in STYLE if counts[k]]
    handles.append(Patch(facecolor=PILLAR_COLOUR, label=f"pillar {pillar_size:g} m  ({len(classified.pillars)})"))
    handles.append(Patch(facecolor="white", edgecolor=WALL_COLOUR, linewidth=2, label="perimeter wall"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.09, 1.0), fontsize=8, frameon=False,
              title="cell type (count)", title_fontsize=9, alignment="left", borderaxespad=0.0)
    ax.text(1.09, 0.0, "arrows: bays point to their lane;\nstraight lanes show their axis;\n"
            "corners the bisector, T-junctions the stem", transform=ax.transAxes, fontsize=7,
            color="#444444", va="bottom", ha="left")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, format="png", bbox_inches="tight", pad_inches=0.2)
    except OSError as exc:
        raise GarageError(f"cannot write the map ({exc.strerror or exc})", str(path)) from None
    return path
