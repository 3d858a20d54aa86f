"""The scene builder: structure, pillars, walls, markings, bays, lamps and the glTF export (no SAPIEN)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from omegaconf import OmegaConf

from garage_exp.scene.schema import GarageConf, LightConf
from garage_exp.core.errors import GarageError
from garage_exp.plan import classify, load_plan, plan_from_lists
from garage_exp.plan.features import UNIT
from garage_exp.scene import materials as mat
from garage_exp.scene.bays import BAY_TYPES, bay_count, bays, overlap, pillar_rect
from garage_exp.scene.description import Box, Entity, Mesh, Pose
from garage_exp.scene.lamps import build_lamps, lit
from garage_exp.scene.markings import STOP_WIDTH, build_markings
from garage_exp.scene.structure import build_garage, build_structure, wall_openings

ROOT = Path(__file__).resolve().parent.parent
GARAGE = GarageConf()
EPS = 1e-6


def tiny():
    return classify(load_plan(ROOT / "plans" / "tiny.yaml"))


def lane_along_x():
    """One lane along x with 3-bay cells on both sides; entrance on the west, exit on the east."""
    return classify(plan_from_lists([[0, 0, 0, 0], [2, 1, 1, 3], [0, 0, 0, 0]], [5.0, 6.0, 5.0], [7.5] * 4, "along_x"))


def lane_along_y():
    return classify(plan_from_lists([[0, 2, 0], [0, 1, 0], [0, 1, 0], [0, 3, 0]], [7.5] * 4, [5.0, 6.0, 5.0],
                                    "along_y"))


def junctions():
    """A crossroads at (2, 2) and a T-junction at (4, 2) whose stem points north."""
    S = [[0, 0, 2, 0, 0],
         [0, 0, 1, 0, 0],
         [1, 1, 1, 1, 1],
         [0, 0, 1, 0, 0],
         [1, 1, 1, 1, 3]]
    return classify(plan_from_lists(S, [5.0, 5.0, 6.0, 5.0, 6.0], [5.0, 5.0, 6.0, 5.0, 6.0], "junctions"))


def world_rects(entity: Entity) -> list[tuple[float, float, float, float]]:
    """Footprints of an entity's boxes (everything the builder makes is axis-aligned)."""
    out = []
    for b in entity.shapes:
        assert entity.pose.yaw == 0.0 and b.offset.yaw == 0.0
        x, y = entity.pose.x + b.offset.x, entity.pose.y + b.offset.y
        out.append((x - b.size[0] / 2, y - b.size[1] / 2, x + b.size[0] / 2, y + b.size[1] / 2))
    return out


def z_range(entity: Entity) -> tuple[float, float]:
    return (min(entity.pose.z + b.offset.z - b.size[2] / 2 for b in entity.shapes),
            max(entity.pose.z + b.offset.z + b.size[2] / 2 for b in entity.shapes))


def inside(r, outer) -> bool:
    return r[0] >= outer[0] - EPS and r[1] >= outer[1] - EPS and r[2] <= outer[2] + EPS and r[3] <= outer[3] + EPS


def marking_rects(classified, i, j, garage=GARAGE):
    found = [e for e in build_markings(classified, garage) if e.name == f"marking_{i}_{j}"]
    return [(r, b.material.name) for e in found for r, b in zip(world_rects(e), e.shapes)]


# ---- cells, pillars, walls, ceiling ---------------------------------------------------------------------


def test_every_cell_is_covered_by_its_surface():
    c = tiny()
    entities = build_structure(c, GARAGE)
    for cell in c.all_cells():
        x, y = c.plan.cell_center(cell.i, cell.j)
        under = [e for e in entities if e.name.startswith(("floor_", "obstacle_"))
                 and any(inside((x, y, x, y), r) for r in world_rects(e))]
        assert len(under) == 1, (cell.i, cell.j)
        material = under[0].shapes[0].material
        if cell.kind == "obstacle":
            assert material is mat.OBSTACLE and z_range(under[0]) == pytest.approx((0.0, GARAGE.ceiling_height))
        else:
            expected = mat.ASPHALT if cell.driveable else mat.FREE_FLOOR if cell.type == "type4" else mat.BAY_FLOOR
            assert material is expected and z_range(under[0])[1] == pytest.approx(0.0)


def test_floor_cells_merge_along_rows():
    c = lane_along_x()
    floors = [e for e in build_structure(c, GARAGE) if e.name.startswith("floor_")]
    # Bay rows are one run each; the lane row is one run (entrance, lanes and exit are all asphalt).
    assert len(floors) == 3


def test_pillars_of_the_tiny_plan():
    c = tiny()
    plan = c.plan
    pillars = {e.name: e for e in build_structure(c, GARAGE) if e.name.startswith("pillar_")}
    assert len(pillars) == len(c.pillars) == 9
    size = GARAGE.pillar_size
    for p in c.pillars:
        e = pillars[f"pillar_{p.a}_{p.b}"]
        vx, vy = plan.vertex(p.a, p.b)
        assert (e.pose.x, e.pose.y) == pytest.approx((vx + p.sx * size / 2, vy + p.sy * size / 2))
        assert all(b.size[:2] == pytest.approx((size, size)) for b in e.shapes)
        assert z_range(e) == pytest.approx((0.0, GARAGE.ceiling_height))
        (rect,) = {r for r in world_rects(e)}
        touched = [cell for cell in c.all_cells() if overlap(rect, plan.cell_rect(cell.i, cell.j)) > EPS]
        assert not [cell for cell in touched if cell.driveable], e.name
        assert any(cell.kind == "parking" for cell in touched), e.name


def test_walls_leave_openings_at_entrance_and_exit_only():
    c = tiny()
    plan = c.plan
    t = GARAGE.wall_thickness
    walls = [r for e in build_structure(c, GARAGE) if e.name.startswith("wall_") for r in world_rects(e)[:1]]
    assert wall_openings(c) == {("W", 1), ("S", 2)}  # entrance (1, 0) opens west, exit (3, 2) south
    x0, y0, x1, y1 = plan.cell_rect(1, 0)
    assert not any(overlap(w, (-t, y0, 0.0, y1)) > EPS for w in walls)
    x0, y0, x1, y1 = plan.cell_rect(3, 2)
    assert not any(overlap(w, (x0, -t, x1, 0.0)) > EPS for w in walls)
    # Everything else of the ring around the footprint is wall, without overlaps.
    width, depth = plan.size
    ring = (width + 2 * t) * (depth + 2 * t) - width * depth
    gaps = t * plan.R[1] + t * plan.C[2]
    assert sum((w[2] - w[0]) * (w[3] - w[1]) for w in walls) == pytest.approx(ring - gaps)
    assert all(overlap(a, b) < EPS for k, a in enumerate(walls) for b in walls[k + 1:])


def test_entrance_on_a_corner_opens_only_its_mouth():
    c = classify(plan_from_lists([[2, 1, 3], [0, 0, 0]], [6.0, 5.0], [6.0, 6.0, 6.0], "corner_mouths"))
    assert wall_openings(c) == {("W", 0), ("E", 0)}


def test_ceiling_covers_footprint_and_walls():
    c = tiny()
    (ceiling,) = [e for e in build_structure(c, GARAGE) if e.name == "ceiling"]
    width, depth = c.plan.size
    t = GARAGE.wall_thickness
    assert world_rects(ceiling)[0] == pytest.approx((-t, -t, width + t, depth + t))
    assert z_range(ceiling) == pytest.approx((GARAGE.ceiling_height, GARAGE.ceiling_height + GARAGE.slab_thickness))


# ---- markings --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("build, cells, long_axis", [
    (lane_along_x, [(1, 1), (1, 2)], 0),
    (lane_along_y, [(1, 1), (2, 1)], 1),
])
def test_straight_lane_dashes_run_along_the_lane(build, cells, long_axis):
    c = build()
    for i, j in cells:
        dashes = [r for r, name in marking_rects(c, i, j) if name == mat.LANE_YELLOW.name]
        assert len(dashes) >= 2
        cx, cy = c.plan.cell_center(i, j)
        for r in dashes:
            long_side, short_side = (r[2] - r[0], r[3] - r[1])[long_axis], (r[2] - r[0], r[3] - r[1])[1 - long_axis]
            assert long_side > 4 * short_side and short_side == pytest.approx(GARAGE.marking_width)
            centre = ((r[0] + r[2]) / 2, (r[1] + r[3]) / 2)
            assert centre[1 - long_axis] == pytest.approx((cx, cy)[1 - long_axis])  # on the centre line
            assert inside(r, c.plan.cell_rect(i, j))


def test_corner_centre_line_bends_through_the_cell_centre():
    c = tiny()
    assert c.cell(1, 2).type == "corner" and set(c.cell(1, 2).lanes) == {"S", "W"}
    cx, cy = c.plan.cell_center(1, 2)
    rects = [r for r, _ in marking_rects(c, 1, 2)]
    along_x = [r for r in rects if r[2] - r[0] > r[3] - r[1]]
    along_y = [r for r in rects if r[3] - r[1] > r[2] - r[0]]
    assert along_x and along_y
    assert all(r[2] <= cx + EPS for r in along_x)  # the west half only
    assert all(r[3] <= cy + EPS for r in along_y)  # the south half only


def test_stop_lines_at_crossroads_and_t_junction():
    c = junctions()
    assert c.cell(2, 2).type == "crossroads" and c.cell(4, 2).type == "t_junction"
    stops = [r for r, name in marking_rects(c, 2, 2) if name == mat.LANE_WHITE.name]
    assert len(stops) == 4
    assert all(min(r[2] - r[0], r[3] - r[1]) == pytest.approx(STOP_WIDTH) for r in stops)
    x0, y0, x1, y1 = c.plan.cell_rect(4, 2)
    cx = (x0 + x1) / 2
    (stem,) = [r for r, name in marking_rects(c, 4, 2) if name == mat.LANE_WHITE.name]
    # Across the stem (north) near its edge, on the right of a car driving south: the west half.
    assert stem[2] - stem[0] > stem[3] - stem[1]
    assert y1 - 1.0 < stem[1] < stem[3] <= y1 and stem[0] >= x0 and stem[2] <= cx + EPS
    assert not [r for r, name in marking_rects(c, 4, 2) if name == mat.LANE_YELLOW.name]


def test_bay_lines_are_perpendicular_to_the_lane_and_drawn_once():
    c = lane_along_x()
    lines = [r for j in range(4) for r, name in marking_rects(c, 0, j) if name == mat.LANE_WHITE.name]
    # Four 7.5 m cells of 3 bays: 3 lines each plus the last cell's far edge.
    assert len(lines) == 4 * 3 + 1
    for r in lines:
        assert r[3] - r[1] == pytest.approx(c.plan.R[0]) and r[2] - r[0] == pytest.approx(GARAGE.marking_width)
    xs = sorted((r[0] + r[2]) / 2 for r in lines)
    assert min(np.diff(xs)) > 2.0
    assert all(inside(r, (0.0, 0.0) + c.plan.size) for r in lines)


def test_wear_fades_paint_and_drops_pieces_deterministically():
    c = lane_along_x()
    fresh = build_markings(c, GARAGE)
    worn = build_markings(c, replace(GARAGE, marking_wear=0.6))
    assert worn == build_markings(c, replace(GARAGE, marking_wear=0.6))
    count = lambda es: sum(len(e.shapes) for e in es)  # noqa: E731
    assert 0.5 * count(fresh) < count(worn) < count(fresh)
    assert count(build_markings(c, replace(GARAGE, marking_wear=0.9))) <= count(worn)
    assert build_markings(c, replace(GARAGE, marking_wear=1.0)) == []
    paint = {b.material.color for e in fresh for b in e.shapes}
    faded = {b.material.color for e in worn for b in e.shapes}
    assert not paint & faded
    white = next(b.material for e in worn for b in e.shapes if b.material.name.startswith("paint_white"))
    expected = mat.LANE_WHITE.color[0] + 0.6 * (mat.BAY_FLOOR.color[0] - mat.LANE_WHITE.color[0])
    assert white.color[0] == pytest.approx(expected)


# ---- bays ------------------------------------------------------------------------------------------------


def shipped(name):
    return lambda: classify(load_plan(ROOT / "plans" / f"{name}.yaml"))


SHIPPED = [pytest.param(shipped(p.stem), id=p.stem) for p in sorted((ROOT / "plans").glob("*.yaml"))]


@pytest.mark.parametrize("build", [tiny, lane_along_x, lane_along_y, junctions, *SHIPPED])
def test_bays_lie_in_their_cells_clear_of_pillars_and_face_the_lane(build):
    c = build()
    plan = c.plan
    found = bays(c, GARAGE)
    pillars = [pillar_rect(plan, p, GARAGE.pillar_size) for p in c.pillars]
    for bay in found:
        assert c.cell(bay.i, bay.j).type in BAY_TYPES
        assert inside(bay.rect, plan.cell_rect(bay.i, bay.j))
        assert all(overlap(bay.rect, p) < EPS for p in pillars), bay
        ux, uy = UNIT[{0.0: "E", 90.0: "N", 180.0: "W", 270.0: "S"}[bay.yaw]]
        ahead = (bay.x + ux * (bay.depth / 2 + 0.1), bay.y + uy * (bay.depth / 2 + 0.1))
        assert plan.is_driveable(*plan.cell_at(*ahead)), bay
    keys = [(b.i, b.j, b.index) for b in found]
    assert len(keys) == len(set(keys))


def test_bay_count_per_cell_follows_the_bay_width():
    c = lane_along_x()
    found = bays(c, GARAGE)
    per_cell = {(b.i, b.j) for b in found}
    assert per_cell == {(i, j) for i in (0, 2) for j in range(4)}
    assert all(sum(1 for b in found if (b.i, b.j) == key) == 3 for key in per_cell)
    assert {b.yaw for b in found if b.i == 0} == {270.0} and {b.yaw for b in found if b.i == 2} == {90.0}
    assert bay_count(7.5, 2.5) == 3 and bay_count(2.4, 2.5) == 1 and bay_count(6.0, 2.5) == 2


def test_bays_narrow_where_a_pillar_stands():
    c = lane_along_x()
    found = {(b.i, b.j, b.index): b for b in bays(c, GARAGE)}
    # The middle bay of a cell has no pillar; the outer bays of inner cells lose half a pillar.
    assert found[(0, 1, 1)].width == pytest.approx(2.5)
    assert found[(0, 1, 0)].width == pytest.approx(2.5 - GARAGE.pillar_size / 2)
    assert found[(0, 1, 0)].x > 7.5 + 1.25


# ---- lamps -----------------------------------------------------------------------------------------------


def presets() -> list[LightConf]:
    out = []
    for path in sorted((ROOT / "conf" / "light").glob("*.yaml")):
        data = yaml.safe_load(path.read_text())
        out.append(LightConf(**data))
    return out


@pytest.mark.parametrize("build", [tiny, junctions])
def test_lamp_count_is_the_same_for_every_preset_and_lit_lamps_follow_coverage(build):
    c = build()
    layouts = []
    for light in presets() + [LightConf(coverage=0.0), LightConf(coverage=0.5, intensity=7.0, seed=3)]:
        entities, lights = build_lamps(c, GARAGE, light)
        assert len(entities) == len(lights) and [e.name for e in entities] == [x.name for x in lights]
        on = [x for x in lights if x.intensity > 0]
        assert len(on) == round(light.coverage * len(lights))
        assert all(x.intensity == light.intensity for x in on)
        glowing = [e for e in entities if any(b.material.emission[0] > 0 for b in e.shapes)]
        assert {e.name for e in glowing} == {x.name for x in on}
        layouts.append([x.position for x in lights])
    assert all(layout == layouts[0] for layout in layouts)
    assert len(layouts[0]) > 3


def test_lamps_hang_over_open_cells_under_the_ceiling_clear_of_pillars():
    c = tiny()
    entities, lights = build_lamps(c, GARAGE, LightConf())
    pillars = [pillar_rect(c.plan, p, GARAGE.pillar_size) for p in c.pillars]
    for e, light in zip(entities, lights):
        assert c.cell(*c.plan.cell_at(e.pose.x, e.pose.y)).kind != "obstacle"
        (rect,) = world_rects(e)
        assert all(overlap(rect, p) < EPS for p in pillars)
        top = z_range(e)[1]
        assert GARAGE.ceiling_height - 0.5 < top < GARAGE.ceiling_height
        assert light.position[2] == pytest.approx(e.shapes[0].offset.z - 0.15)


def test_lit_lamps_are_spread_evenly_and_seeded():
    on = lit(40, 0.25, seed=1)
    idx = [k for k, v in enumerate(on) if v]
    assert len(idx) == 10 and set(np.diff(idx)) <= {3, 4, 5}
    assert lit(40, 0.25, seed=1) == on
    assert any(lit(40, 0.25, seed=s) != on for s in range(2, 6))
    assert lit(5, 1.0, 0) == [True] * 5 and lit(5, 0.0, 0) == [False] * 5


# ---- the whole garage ------------------------------------------------------------------------------------


def test_build_garage_holds_structure_markings_and_lamps_only():
    c = tiny()
    light = LightConf(ambient=0.03)
    scene = build_garage(c, GARAGE, light)
    assert {e.role for e in scene.entities} == {"structure", "marking", "lamp"}
    assert not scene.cameras and not scene.vehicles()
    names = [e.name for e in scene.entities]
    assert len(names) == len(set(names))
    assert len(scene.lights) == len(scene.by_role("lamp"))
    assert scene.ambient == (0.03, 0.03, 0.03) and scene.ceiling == GARAGE.ceiling_height
    assert scene.bounds == pytest.approx((0.0, 0.0) + c.plan.size)
    assert scene.name == "tiny"


@pytest.mark.parametrize("build", SHIPPED)
def test_every_shipped_plan_builds_with_unique_names_and_lamps_clear_of_pillars(build):
    c = build()
    scene = build_garage(c, GARAGE, LightConf())
    names = [e.name for e in scene.entities]
    assert len(names) == len(set(names))
    assert len(scene.by_role("lamp")) == len(scene.lights) > 0
    assert len([n for n in names if n.startswith("pillar_")]) == len(c.pillars)
    pillars = [pillar_rect(c.plan, p, GARAGE.pillar_size) for p in c.pillars]
    for e in scene.by_role("lamp"):
        assert all(overlap(world_rects(e)[0], p) < EPS for p in pillars)


def test_build_is_deterministic():
    c = junctions()
    light = LightConf(coverage=0.7, seed=5)
    assert build_garage(c, GARAGE, light) == build_garage(c, GARAGE, light)


def test_accepts_hydra_configs():
    c = tiny()
    garage = OmegaConf.structured(GarageConf)
    light = OmegaConf.structured(LightConf(coverage=0.5))
    assert build_garage(c, garage, light) == build_garage(c, GARAGE, LightConf(coverage=0.5))


@pytest.mark.parametrize("garage, light, where", [
    (replace(GARAGE, pillar_size=0.0), LightConf(), "garage.pillar_size"),
    (replace(GARAGE, marking_wear=1.5), LightConf(), "garage.marking_wear"),
    (replace(GARAGE, lamp_size=(1.2,)), LightConf(), "garage.lamp_size"),
    (GARAGE, LightConf(coverage=1.2), "light.coverage"),
    (GARAGE, LightConf(intensity=-1.0), "light.intensity"),
])
def test_bad_factors_raise_one_line(garage, light, where):
    from garage_exp.scene.lamps import check_light
    from garage_exp.scene.structure import check_garage

    with pytest.raises(GarageError) as info:
        check_garage(garage)
        check_light(light)
    assert info.value.where == where and "\n" not in str(info.value)


def test_scene_modifiers_work_on_the_built_scene():
    from garage_exp.scene.modifiers import marking_wear, pillar_size

    c = tiny()
    scene = build_garage(c, GARAGE, LightConf())
    pillar_size(scene, c, GARAGE, size=0.9)
    assert all(b.size[:2] == (0.9, 0.9) for e in scene.entities if e.name.startswith("pillar_") for b in e.shapes)
    before = sum(len(e.shapes) for e in scene.by_role("marking"))
    marking_wear(scene, c, GARAGE, wear=0.8)
    assert 0 < sum(len(e.shapes) for e in scene.by_role("marking")) < before


# ---- glTF ------------------------------------------------------------------------------------------------


def test_glb_export_loads_back_with_the_same_bounds(tmp_path):
    import trimesh

    from garage_exp.scene.gltf import export_glb

    car = tmp_path / "car.glb"
    trimesh.creation.box(extents=(4.0, 1.8, 1.5), transform=trimesh.transformations.translation_matrix(
        (0.0, 0.0, 0.75))).export(car)
    c = tiny()
    scene = build_garage(c, GARAGE, LightConf(coverage=0.5))
    # A car parked far outside the garage, turned 90 degrees, so the bounds show it is placed and turned.
    scene.entities.append(Entity("parked_0", "parked", Pose(30.0, 5.0, 0.0, 90.0), [Mesh(str(car))]))
    out = export_glb(scene, tmp_path / "scene.glb")
    loaded = trimesh.load(out, force="scene")
    xs, ys, zs = [], [], []
    for e in scene.entities:
        if all(isinstance(b, Box) for b in e.shapes):
            for r, b in zip(world_rects(e), e.shapes):
                xs += [r[0], r[2]]
                ys += [r[1], r[3]]
                zs += [e.pose.z + b.offset.z - b.size[2] / 2, e.pose.z + b.offset.z + b.size[2] / 2]
    xs += [30.0 - 0.9, 30.0 + 0.9]
    ys += [5.0 - 2.0, 5.0 + 2.0]
    zs += [0.0, 1.5]
    # Y up: (x, y, z) -> (x, z, -y).
    expected = [[min(xs), min(zs), -max(ys)], [max(xs), max(zs), -min(ys)]]
    assert loaded.bounds == pytest.approx(np.array(expected), abs=1e-4)
    materials = [getattr(g.visual, "material", None) for g in loaded.geometry.values()]
    emissive = [m.emissiveFactor for m in materials if getattr(m, "emissiveFactor", None) is not None]
    assert emissive and max(max(e) for e in emissive) > 0.5
    assert any(name.startswith("pillar_") for name in loaded.graph.nodes)


def test_glb_export_names_a_missing_vehicle_mesh(tmp_path):
    from garage_exp.scene.gltf import export_glb

    scene = build_garage(tiny(), GARAGE, LightConf())
    scene.entities.append(Entity("parked_0", "parked", Pose(), [Mesh(str(tmp_path / "missing.glb"))]))
    with pytest.raises(GarageError, match="missing.glb"):
        export_glb(scene, tmp_path / "scene.glb")
