"""The garage's static structure from a classified plan, built in the method's order: cells (floors and
obstacle blocks), the pillar grid, the walls and the ceiling. `build_garage` adds markings and lamps.

The floor's top is z = 0 (vehicles stand on it); the ceiling's underside is z = garage.ceiling_height.
"""

from __future__ import annotations

from garage_exp.core.errors import GarageError, check_range
from garage_exp.plan.classify import Cell, Classified
from garage_exp.plan.model import OPPOSITE
from garage_exp.scene import materials as mat
from garage_exp.scene.bays import BEAM_DEPTH, Rect, beams, pillar_centre
from garage_exp.scene.description import PILLAR_PREFIX, Box, Entity, Material, Pose, Scene
from garage_exp.scene.lamps import build_lamps
from garage_exp.scene.markings import build_markings

FLOOR_DEPTH = 0.2
WALL_BAND_HEIGHT = 1.0  # the dark band covers bumpers and mirrors
PILLAR_BAND_HEIGHT = 1.0

# (name, minimum, maximum): values outside these are unit or typing mistakes.
GARAGE_RANGES = (
    ("ceiling_height", 1.8, 10.0), ("slab_thickness", 0.05, 3.0), ("pillar_size", 0.05, 3.0),
    ("wall_thickness", 0.05, 3.0), ("bay_width", 1.5, 20.0), ("lamp_spacing", 1.0, 100.0),
    ("marking_width", 0.01, 1.0), ("marking_wear", 0.0, 1.0),
)


def check_garage(garage) -> None:
    """The `garage` group's values."""
    for name, lo, hi in GARAGE_RANGES:
        value = float(getattr(garage, name))
        check_range(value, lo, hi, f"garage.{name}", f"{name} = {value:g}")
    size = tuple(float(v) for v in garage.lamp_size)
    if len(size) != 2 or not all(0.05 <= v <= 5.0 for v in size):
        raise GarageError(f"lamp_size {list(size)} must be two lengths in 0.05-5 m", "garage.lamp_size")


def box_entity(name: str, role: str, rect: Rect, z0: float, z1: float, material: Material) -> Entity:
    """One box spanning `rect` from z0 to z1; the entity sits at the footprint's centre on z = 0."""
    x0, y0, x1, y1 = rect
    return Entity(name, role, Pose((x0 + x1) / 2, (y0 + y1) / 2, 0.0),
                  [Box((x1 - x0, y1 - y0, z1 - z0), material, Pose(0.0, 0.0, (z0 + z1) / 2))])


def banded_entity(name: str, centre: tuple[float, float], size: tuple[float, float], height: float, band: float,
                  lower: Material, upper: Material) -> Entity:
    """A floor-to-ceiling box painted `lower` up to `band` and `upper` above (walls, pillars)."""
    band = min(band, height)
    return Entity(name, "structure", Pose(centre[0], centre[1], 0.0), [
        Box((*size, band), lower, Pose(0.0, 0.0, band / 2)),
        Box((*size, height - band), upper, Pose(0.0, 0.0, (band + height) / 2)),
    ])


def wall_entity(name: str, rect: Rect, garage) -> Entity:
    x0, y0, x1, y1 = rect
    return banded_entity(name, ((x0 + x1) / 2, (y0 + y1) / 2), (x1 - x0, y1 - y0), float(garage.ceiling_height),
                         WALL_BAND_HEIGHT, mat.WALL_BAND, mat.WALL_PAINT)


def surface(cell: Cell) -> Material:
    """What covers a cell: asphalt where cars drive, lighter concrete in bays, plain concrete elsewhere."""
    if cell.kind == "obstacle":
        return mat.OBSTACLE
    if cell.driveable:
        return mat.ASPHALT
    return mat.FREE_FLOOR if cell.type == "type4" else mat.BAY_FLOOR


def build_cells(classified: Classified, garage) -> list[Entity]:
    """Floors and obstacle blocks, one box per run of same-material cells along a row."""
    plan = classified.plan
    height = float(garage.ceiling_height)
    xs, ys = plan.x_edges, plan.y_edges
    out = []
    for i, row in enumerate(classified.cells):
        j0 = 0
        for j in range(1, len(row) + 1):
            if j < len(row) and surface(row[j]) is surface(row[j0]):
                continue
            material = surface(row[j0])
            rect = (float(xs[j0]), float(ys[i + 1]), float(xs[j]), float(ys[i]))
            if material is mat.OBSTACLE:
                out.append(box_entity(f"obstacle_{i}_{j0}_{j - 1}", "structure", rect, 0.0, height, material))
            else:
                out.append(box_entity(f"floor_{i}_{j0}_{j - 1}", "structure", rect, -FLOOR_DEPTH, 0.0, material))
            j0 = j
    return out


def build_pillars(classified: Classified, garage) -> list[Entity]:
    """One square pillar per grid vertex of the plan, shifted off the lanes; named pillar_<a>_<b>."""
    plan = classified.plan
    size, height = float(garage.pillar_size), float(garage.ceiling_height)
    out = []
    for p in classified.pillars:
        out.append(banded_entity(f"{PILLAR_PREFIX}{p.a}_{p.b}", pillar_centre(plan, p, size), (size, size), height,
                                 PILLAR_BAND_HEIGHT, mat.PILLAR_BAND, mat.PILLAR_PAINT))
    return out


def wall_openings(classified: Classified) -> set[tuple[str, int]]:
    """Perimeter edges left open: (side, cell index along that side) for each entrance or exit cell on the
    perimeter. The mouth is the edge opposite the cell's lane; a cell without such an edge opens all its
    perimeter edges."""
    m, n = classified.plan.shape
    out = set()
    for cell in classified.of_type("entrance", "exit"):
        edges = {d: k for d, k, on in (("N", cell.j, cell.i == 0), ("S", cell.j, cell.i == m - 1),
                                       ("W", cell.i, cell.j == 0), ("E", cell.i, cell.j == n - 1)) if on}
        mouths = [d for d in edges if OPPOSITE[d] in cell.lanes]
        out.update((d, edges[d]) for d in (mouths or edges))
    return out


def _closed_runs(spans: list[tuple[float, float, bool]]) -> list[tuple[float, float]]:
    """Merge consecutive closed spans (start, end, closed) into runs."""
    runs: list[tuple[float, float]] = []
    for start, end, closed in spans:
        if not closed:
            continue
        if runs and abs(runs[-1][1] - start) < 1e-9:
            runs[-1] = (runs[-1][0], end)
        else:
            runs.append((start, end))
    return runs


def build_walls(classified: Classified, garage) -> list[Entity]:
    """Perimeter walls outside the footprint; the N and S walls also close the corners."""
    plan = classified.plan
    t = float(garage.wall_thickness)
    width, depth = plan.size
    xs, ys = plan.x_edges, plan.y_edges
    m, n = plan.shape
    openings = wall_openings(classified)
    out = []
    for side in ("N", "S"):
        spans = [(-t, 0.0, True)]
        spans += [(float(xs[j]), float(xs[j + 1]), (side, j) not in openings) for j in range(n)]
        spans += [(width, width + t, True)]
        y0, y1 = (depth, depth + t) if side == "N" else (-t, 0.0)
        for k, (a, b) in enumerate(_closed_runs(spans)):
            out.append(wall_entity(f"wall_{side}_{k}", (a, y0, b, y1), garage))
    for side in ("W", "E"):
        # Rows run from the top (largest y) down; list spans bottom-up so runs merge in order.
        spans = [(float(ys[i + 1]), float(ys[i]), (side, i) not in openings) for i in reversed(range(m))]
        x0, x1 = (-t, 0.0) if side == "W" else (width, width + t)
        for k, (a, b) in enumerate(_closed_runs(spans)):
            out.append(wall_entity(f"wall_{side}_{k}", (x0, a, x1, b), garage))
    return out


def build_ceiling(classified: Classified, garage) -> list[Entity]:
    """The slab over the footprint and the walls, and the beams under it."""
    width, depth = classified.plan.size
    t, c = float(garage.wall_thickness), float(garage.ceiling_height)
    out = [box_entity("ceiling", "structure", (-t, -t, width + t, depth + t), c, c + float(garage.slab_thickness),
                      mat.CEILING)]
    out += [box_entity(b.name, "structure", b.rect, c - BEAM_DEPTH, c, mat.BEAM) for b in beams(classified, garage)]
    return out


def build_structure(classified: Classified, garage) -> list[Entity]:
    """Cells, then the pillar grid, then the walls and ceiling. The values are checked once, by
    `check_garage` (preflight)."""
    return (build_cells(classified, garage) + build_pillars(classified, garage) + build_walls(classified, garage)
            + build_ceiling(classified, garage))


def build_garage(classified: Classified, garage, light) -> Scene:
    """The empty garage: structure, markings, lamp panels and their lights; no vehicles and no cameras."""
    entities = build_structure(classified, garage)
    entities += build_markings(classified, garage)
    lamp_entities, lights = build_lamps(classified, garage, light)
    entities += lamp_entities
    width, depth = classified.plan.size
    ambient = float(light.ambient)
    return Scene(name=classified.plan.name, entities=entities, lights=lights, ambient=(ambient, ambient, ambient),
                 bounds=(0.0, 0.0, width, depth), ceiling=float(garage.ceiling_height))
