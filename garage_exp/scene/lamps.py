"""Ceiling lamps: emissive panels on a regular grid over every cell but obstacles, each with a point light.

Where the lamps are depends only on the plan and the garage geometry, so every lighting preset has the same
lamps and lights (a renderer's light count, and SAPIEN's compiled shaders, never change). The preset decides
which are on: round(coverage * N) of them, spread evenly along the grid's serpentine order with a seeded
phase, so "dim" is every fourth lamp or so rather than a dark half of the garage.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from garage_exp.core.errors import GarageError, check_range
from garage_exp.core.state import STATE
from garage_exp.plan.classify import Cell, Classified
from garage_exp.scene import materials as mat
from garage_exp.scene.bays import BAY_TYPES, BEAM_DEPTH, Rect, beams, overlap, pillar_rect, pillars_by_vertex
from garage_exp.scene.description import Box, Entity, Light, Pose

PANEL_GAP = 0.05  # between the ceiling (or a beam's underside) and the panel's top
PANEL_THICKNESS = 0.04
LIGHT_BELOW = 0.15  # the point light sits this far below the panel's centre, clear of its box
EPS = 1e-9


@dataclass(frozen=True)
class LampSite:
    x: float
    y: float
    z: float  # panel centre
    along_x: bool  # the panel's long side runs along x


def grid(length: float, spacing: float) -> list[float]:
    """Lamp positions along one axis: round(length / spacing) of them (at least one), centred."""
    n = max(1, round(length / spacing))
    start = (length - (n - 1) * spacing) / 2
    return [start + k * spacing for k in range(n)]


def _along_x(cell: Cell) -> bool:
    """Panels run with the lane: along a straight lane's axis, parallel to a bay row's lane edge."""
    if cell.driveable:
        return cell.type != "straight" or cell.rotation % 180.0 == 0.0
    if cell.type in BAY_TYPES:
        return cell.rotation % 180.0 != 0.0
    return True


def _panel(x: float, y: float, size: tuple[float, float], along_x: bool) -> Rect:
    hx, hy = (size[0] / 2, size[1] / 2) if along_x else (size[1] / 2, size[0] / 2)
    return (x - hx, y - hy, x + hx, y + hy)


class _Obstructions:
    """What a panel must not cut into (pillars, obstacle blocks, the walls) and the beams it hangs under,
    looked up through the cells under the panel."""

    def __init__(self, classified: Classified, garage):
        self.classified = classified
        self.plan = classified.plan
        size = float(garage.pillar_size)
        self.pillars = {v: pillar_rect(self.plan, p, size) for v, p in pillars_by_vertex(classified).items()}
        self.beams: dict[tuple[int, int], list[Rect]] = {}
        for beam in beams(classified, garage):
            for c in beam.cells:
                self.beams.setdefault(c, []).append(beam.rect)

    def _cells(self, rect: Rect) -> tuple[range, range]:
        plan = self.plan
        j0 = int(np.searchsorted(plan.x_edges, rect[0], side="right")) - 1
        j1 = int(np.searchsorted(plan.x_edges, rect[2], side="left")) - 1
        i0 = int(np.searchsorted(-plan.y_edges, -rect[3], side="right")) - 1
        i1 = int(np.searchsorted(-plan.y_edges, -rect[1], side="left")) - 1
        m, n = plan.shape
        return range(max(i0, 0), min(i1, m - 1) + 1), range(max(j0, 0), min(j1, n - 1) + 1)

    def blocked(self, rect: Rect) -> bool:
        width, depth = self.plan.size
        if rect[0] < -EPS or rect[1] < -EPS or rect[2] > width + EPS or rect[3] > depth + EPS:
            return True
        rows, cols = self._cells(rect)
        for i in rows:
            for j in cols:
                if self.classified.cell(i, j).kind == "obstacle" and overlap(rect, self.plan.cell_rect(i, j)) > EPS:
                    return True
        for a in range(rows.start, rows.stop + 1):
            for b in range(cols.start, cols.stop + 1):
                pr = self.pillars.get((a, b))
                if pr is not None and overlap(rect, pr) > EPS:
                    return True
        return False

    def under_beam(self, rect: Rect) -> bool:
        rows, cols = self._cells(rect)
        return any(overlap(rect, br) > EPS for i in rows for j in cols for br in self.beams.get((i, j), ()))


# A search builds the scene of every draw, and the wide space's lights change per draw, its garages seldom: the
# sites (a pure function of the plan and the garage's settings; 0.01 s, a quarter of a garage's build) are kept
# per classified plan and garage settings.
_SITES: dict = STATE.cache("scene.lamps.sites", "process")
SITES_KEPT = 32


def lamp_sites(classified: Classified, garage) -> list[LampSite]:
    """Grid points over non-obstacle cells, in serpentine order (row by row from the top, alternating
    direction), so neighbours in the list are neighbours in the garage. A panel that would cut into a pillar
    is turned; if it still would, the lamp is left out."""
    try:
        key = (id(classified), tuple(sorted(dict(garage).items())))
        hash(key)
    except TypeError:  # a setting that is not plain data: not kept
        return _lamp_sites(classified, garage)
    held = _SITES.get(key)
    if held is None or held[0] is not classified:
        if len(_SITES) >= SITES_KEPT:
            _SITES.clear()
        held = _SITES[key] = (classified, _lamp_sites(classified, garage))
    return list(held[1])


def _lamp_sites(classified: Classified, garage) -> list[LampSite]:
    plan = classified.plan
    width, depth = plan.size
    spacing = float(garage.lamp_spacing)
    size = tuple(float(v) for v in garage.lamp_size)
    ceiling = float(garage.ceiling_height)
    obstructions = _Obstructions(classified, garage)
    xs = grid(width, spacing)
    out = []
    for r, y in enumerate(reversed(grid(depth, spacing))):
        for x in xs if r % 2 == 0 else reversed(xs):
            ij = plan.cell_at(x, y)
            if ij is None or classified.cell(*ij).kind == "obstacle":
                continue
            first = _along_x(classified.cell(*ij))
            along_x = next((o for o in (first, not first) if not obstructions.blocked(_panel(x, y, size, o))), None)
            if along_x is None:
                continue
            top = ceiling - PANEL_GAP - (BEAM_DEPTH if obstructions.under_beam(_panel(x, y, size, along_x)) else 0.0)
            out.append(LampSite(x, y, top - PANEL_THICKNESS / 2, along_x))
    return out


def lit(n: int, coverage: float, seed: int) -> list[bool]:
    """Which of n lamps are on: round(coverage * n), evenly spaced with a seeded phase."""
    count = int(round(coverage * n))
    if count >= n:
        return [True] * n
    on = [False] * n
    if count == 0:
        return on
    phase = float(np.random.default_rng(seed).random())
    for k in range(count):
        # Steps of n / count >= 1 keep the indices distinct.
        on[int((k + phase) * n / count)] = True
    return on


# Colour temperatures (K) the Planckian-locus fit below covers (Kim et al. 2002: 1667-25000 K), kept to lamps.
TEMPERATURE_RANGE = (1700.0, 12000.0)
# CIE XYZ -> linear sRGB (IEC 61966-2-1, D65).
_XYZ_TO_SRGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])


def kelvin_rgb(kelvin: float) -> tuple[float, float, float]:
    """A black body's colour at `kelvin` as linear sRGB, its largest channel 1: the CIE 1931 xy of the Planckian
    locus by Kim et al.'s cubic fit (US patent 7024034; the one colour-science uses), then XYZ -> sRGB."""
    t = float(kelvin)
    if t <= 4000.0:
        x = -0.2661239e9 / t**3 - 0.2343589e6 / t**2 + 0.8776956e3 / t + 0.179910
    else:
        x = -3.0258469e9 / t**3 + 2.1070379e6 / t**2 + 0.2226347e3 / t + 0.240390
    if t <= 2222.0:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif t <= 4000.0:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    rgb = (_XYZ_TO_SRGB @ np.array([x / y, 1.0, (1.0 - x - y) / y])).clip(min=0.0)
    return tuple(float(round(c, 4)) for c in rgb / rgb.max())


def lamp_colour(light) -> tuple[float, float, float]:
    """The lamps' colour: their colour temperature's when `light.temperature` is set, else `light.colour`."""
    if getattr(light, "temperature", None) is not None:
        return kelvin_rgb(float(light.temperature))
    return tuple(float(c) for c in light.colour)


def check_light(light, where: str = "light") -> None:
    """The `light` group's values (or another light preset's, at `where`: `look.blank_light`)."""
    for name, lo, hi in (("coverage", 0.0, 1.0), ("intensity", 0.0, 1000.0), ("ambient", 0.0, 1.0)):
        value = float(getattr(light, name))
        check_range(value, lo, hi, f"{where}.{name}", f"{name} = {value:g}")
    if getattr(light, "temperature", None) is not None:
        value = float(light.temperature)
        check_range(value, *TEMPERATURE_RANGE, f"{where}.temperature", f"temperature = {value:g} K")
    colour = tuple(float(c) for c in light.colour)
    if len(colour) != 3 or not all(0.0 <= c <= 1.0 for c in colour):
        raise GarageError(f"colour {list(colour)} must be three values in 0-1", f"{where}.colour")


def build_lamps(classified: Classified, garage, light) -> tuple[list[Entity], list[Light]]:
    """A panel entity (role "lamp") and a point light per lamp site, both named lamp_<k>. Off lamps keep
    their light at intensity 0 and a dark panel. The values are checked once, by `check_light` (preflight)."""
    size = tuple(float(v) for v in garage.lamp_size)
    colour = lamp_colour(light)
    intensity = float(light.intensity)
    sites = lamp_sites(classified, garage)
    on_material = mat.lamp_on(colour, intensity)
    entities, lights = [], []
    for k, (site, on) in enumerate(zip(sites, lit(len(sites), float(light.coverage), int(light.seed)))):
        extent = (size[0], size[1]) if site.along_x else (size[1], size[0])
        name = f"lamp_{k}"
        entities.append(Entity(name, "lamp", Pose(site.x, site.y, 0.0), [
            Box((*extent, PANEL_THICKNESS), on_material if on else mat.LAMP_OFF, Pose(0.0, 0.0, site.z))]))
        lights.append(Light(name, (site.x, site.y, site.z - LIGHT_BELOW), colour, intensity if on else 0.0))
    return entities, lights
