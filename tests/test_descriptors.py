"""Descriptors that tell failures apart on a wide space (issue 49, item 7; garage_exp/search/descriptors.py): each a
registered function measured from a trial's own frame table, whose new columns (the target's 3D height, the
lamps' direct light at it, the camera's height) come from ground truth; the wide cells (864) put failures of
different kinds in different cells."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.perception.groundtruth import direct_light, ground_truth, mask_box
from garage_exp.render import Frame
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import CameraSpec, Entity, Light, Pose, Scene
from garage_exp.search import archive
from garage_exp.search.descriptors import DESCRIPTORS, register_descriptor
from garage_exp.search.schema import SearchConf, default_descriptors, wide_descriptors

SHIPPED = ("kind", "target_class", "target", "camera", "occluder", "distance", "visible", "box", "light",
           "camera_height", "luminance")


def search_conf(descriptors) -> object:
    return OmegaConf.merge(OmegaConf.structured(SearchConf), {"descriptors": descriptors})


def row(**kw) -> dict:
    """A fair frame's row (visible, 60 px tall, inside the picture) with the ground-truth columns."""
    base = {"shot": 0, "camera": "front", "target": "target", "target_kind": "vehicle", "distance": 9.0,
            "visible_fraction": 1.0, "box_height": 60, "truncation": 0.0, "occluder": "none", "target_height": 1.45,
            "target_light": 0.9, "camera_height": 1.55, "composite": 0.5}
    return {**base, **kw}


def test_every_shipped_descriptor_is_registered_and_a_users_own_is_one_function(tmp_path):
    assert set(SHIPPED) <= set(DESCRIPTORS)
    assert {DESCRIPTORS[n].kind for n in SHIPPED} == {"category", "number"}

    @register_descriptor("lateral", "number", "how far off the ego's axis the target stands (m)")
    def lateral(first, _out, _frame):
        return abs(float(first["distance"]) * math.sin(math.radians(float(first["off_axis"]))))

    try:
        search = search_conf([{"source": "lateral", "edges": [0, 1, 10]}, {"source": "light", "edges": [0, 1, 9]}])
        archive.check_descriptors(search.descriptors)
        got = archive.measure(pd.DataFrame([row(off_axis=30.0, distance=4.0)]), tmp_path, None, search)
        assert got == {"lateral": pytest.approx(2.0), "light": 0.9}
        assert archive.Grid(search.descriptors).index(got) == (1, 0)
    finally:
        DESCRIPTORS.pop("lateral")
    with pytest.raises(GarageError, match=r"search.descriptors\[0\].source: unknown descriptor source 'lateral'"):
        archive.check_descriptors(search.descriptors)
    with pytest.raises(ValueError, match="a descriptor is a category or a number"):
        register_descriptor("x", "colour", "")


@pytest.mark.parametrize(("kw", "want"), [
    ({"target_kind": "person", "target_height": 1.15, "target": "child"}, "small_person"),
    ({"target_kind": "person", "target_height": 0.98, "target": "walker"}, "small_person"),  # crouching adult
    ({"target_kind": "person", "target_height": 1.78, "target": "walker"}, "person"),
    ({"target_kind": "vehicle", "target_height": 1.45}, "car"),
    ({"target_kind": "vehicle", "target_height": 2.05}, "tall_vehicle"),
    ({"target_height": 1.69}, "car"),  # a vehicle-only table has no target_kind
    ({"target_height": float("nan")}, ""),  # a table without heights: no class, no cell
])
def test_the_target_class_comes_from_its_kind_and_3d_height(kw, want, tmp_path):
    table = pd.DataFrame([row(**kw)])
    if "target_kind" not in kw:
        table = table.drop(columns="target_kind")
    got = archive.measure(table, tmp_path, None, search_conf([{"source": "target_class",
                                                                "values": ["small_person", "person", "car"]}]))
    assert got["target_class"] == want


def test_the_new_numbers_are_read_at_the_first_fair_frame_and_an_old_table_has_none(tmp_path):
    table = pd.DataFrame([
        row(shot=0, visible_fraction=0.3, target_light=5.0, camera_height=9.0, box_height=99),  # hidden: not fair
        row(shot=1, visible_fraction=0.8, target_light=0.12, camera_height=0.6, box_height=41),  # the first fair one
        row(shot=2, target_light=0.5)])
    search = search_conf([{"source": s, "edges": [0, 1, 100]} for s in ("light", "camera_height", "box")])
    assert archive.measure(table, tmp_path, None, search) == {"light": 0.12, "camera_height": 0.6, "box": 41.0}
    old = table.drop(columns=["target_light", "camera_height", "target_height"])
    got = archive.measure(old, tmp_path, None, search)
    assert math.isnan(got["light"]) and math.isnan(got["camera_height"])
    assert archive.Grid(search.descriptors).index(got) is None  # out of the archive, as a trial without a fair frame


# Failures of different kinds, as their first fair rows: each must land in a cell of its own among the wide cells.
KINDS = {
    "child behind a pillar, dim, close, roof camera": row(target_kind="person", target_height=1.15,
                                                          occluder="pillar", distance=6.0, visible_fraction=0.6,
                                                          target_light=0.08),
    "the same child seen by a grille camera": row(target_kind="person", target_height=1.15, occluder="pillar",
                                                  distance=6.0, visible_fraction=0.6, target_light=0.08,
                                                  camera_height=0.7),
    "the same child in bright light": row(target_kind="person", target_height=1.15, occluder="pillar", distance=6.0,
                                          visible_fraction=0.6, target_light=1.1),
    "a crouching adult behind a parked car": row(target_kind="person", target_height=0.98, occluder="vehicle",
                                                 distance=12.0, visible_fraction=0.8),
    "an adult in the open far away": row(target_kind="person", target_height=1.78, distance=22.0),
    "a person hidden by another person": row(target_kind="person", target_height=1.78, occluder="person",
                                             visible_fraction=0.7),
    "a car behind a pillar far away": row(occluder="pillar", distance=21.0, visible_fraction=0.55),
    "a car behind a wall (structure joins the pillar's cell)": row(occluder="structure", distance=21.0,
                                                                   visible_fraction=0.55, target_light=0.3),
    "a van in the open": row(target_height=2.1, target_light=0.3),
    "a van behind a van": row(target_height=2.1, occluder="vehicle", visible_fraction=0.9, target_light=0.3),
}


def test_the_wide_cells_are_several_hundred_and_tell_failure_kinds_apart(tmp_path):
    search = search_conf([OmegaConf.structured(d) for d in wide_descriptors()])
    archive.check_descriptors(search.descriptors)
    grid = archive.Grid(search.descriptors)
    assert int(np.prod(grid.dims)) == 864 and grid.dims == [4, 4, 3, 3, 3, 2]
    assert [d.source for d in grid.descriptors] == ["target_class", "occluder", "distance", "visible", "light",
                                                    "camera_height"]
    cells = {name: grid.index(archive.measure(pd.DataFrame([r]), tmp_path, None, search)) for name, r in KINDS.items()}
    assert None not in cells.values(), cells
    assert len(set(cells.values())) == len(KINDS), cells
    # the shipped default cells, kind x occluder x distance x visible, put the first three in one cell
    default = archive.Grid(search_conf([OmegaConf.structured(d) for d in default_descriptors()]).descriptors)
    first = [default.index(archive.measure(pd.DataFrame([r]), tmp_path, None, search_conf(
        [OmegaConf.structured(d) for d in default_descriptors()]))) for r in list(KINDS.values())[:3]]
    assert len(set(first)) == 1


# --- the ground truth the new columns come from -------------------------------------------------------------------

def test_the_direct_light_is_the_sum_of_intensity_over_squared_distance():
    lights = [Light("a", (0.0, 0.0, 2.0), intensity=2.0), Light("b", (3.0, 0.0, 0.0), intensity=1.0),
              Light("off", (0.0, 1.0, 0.0), intensity=0.0)]
    scene = Scene("s", lights=lights)
    assert direct_light(scene, (0.0, 0.0, 0.0)) == pytest.approx(2.0 / 4 + 1.0 / 9)
    assert direct_light(scene, (0.0, 0.0, 1.9)) == pytest.approx(2.0 / 0.25 + 1.0 / (9 + 1.9 ** 2))  # within 0.5 m
    assert direct_light(Scene("dark"), (0.0, 0.0, 0.0)) == 0.0
    dimmer = Scene("s", lights=[Light(lt.name, lt.position, intensity=lt.intensity / 2) for lt in lights])
    assert direct_light(dimmer, (1.0, 1.0, 0.5)) == pytest.approx(direct_light(scene, (1.0, 1.0, 0.5)) / 2)


@pytest.mark.parametrize("cam_height", [0.6, 1.55])
def test_ground_truth_gives_the_targets_height_and_light_and_the_cameras_height(cam_height):
    """A person 1.15 m tall 8 m before a camera, one lamp 2 m above its centre: the record says 1.15 m, the lamp's
    1 / 2^2 and the camera's height; the frame row carries them."""
    from types import SimpleNamespace

    from garage_exp.results.table import frame_row

    person = Entity("child", "target", Pose(8.0, 0.0, 0.0), extent=(0.3, 0.4, 1.15), static=False, kind="person")
    spec = CameraSpec("front", Pose(0.0, 0.0, cam_height), width=320, height=240)
    frame = Frame("front", np.zeros((240, 320, 3), np.uint8), np.zeros((240, 320), np.int32),
                  camera_to_world(Pose(), spec), lens_of(spec), {"child": person.pose})
    uv, _ = frame.project(np.array([[8.0, -0.2, 0.0], [8.0, 0.2, 1.15]]))
    silhouette = np.zeros((240, 320), bool)
    (u1, v1), (u2, v2) = np.floor(uv.min(axis=0)).astype(int), np.ceil(uv.max(axis=0)).astype(int)
    silhouette[v1:v2, u1:u2] = True
    frame.ids[silhouette] = 5
    assert mask_box(silhouette) is not None
    scene = Scene("s", [person], lights=[Light("lamp", (8.0, 0.0, 0.575 + 2.0), intensity=1.0)])
    [truth] = ground_truth(frame, {"child": silhouette}, scene, {"child": 5})
    assert truth.height == pytest.approx(1.15)
    assert truth.light == pytest.approx(0.25)
    assert truth.camera_height == pytest.approx(cam_height)
    shot = SimpleNamespace(index=0, label="x", position=8.0, ego=Pose(), target="child")
    score = SimpleNamespace(per_model=[], composite=0.0, detected=False, false_positives=0)
    got = frame_row(shot, "front", truth, score, [], "person")
    assert (got["target_height"], got["target_light"], got["camera_height"]) == (1.15, 0.25, cam_height)
    assert math.isnan(frame_row(shot, "front", None, score, [])["target_light"])  # out of view


def test_a_wide_archive_draws_only_the_panels_that_hold_a_value(tmp_path):
    """The wide space's 864 cells are 54 panels; drawn all in a strip (6105 px wide) nothing could be read. Past
    MAX_PANELS only the panels holding a value are drawn, wrapped, and the title says how many were left out."""
    from PIL import Image

    from garage_exp.report.archive_cells import draw_cells

    grid = archive.Grid(OmegaConf.create(wide_descriptors()))
    assert len(grid.dims) > 2
    values = {(0, 0) + (0,) * (len(grid.dims) - 2): 0.9, (1, 1) + (1,) * (len(grid.dims) - 2): 0.3}
    assert np.prod(grid.dims[2:]) > 12  # more panels than MAX_PANELS
    width, _ = Image.open(draw_cells(grid, values, tmp_path / "a.png", "difficulty", "difficulty")).size
    assert width <= 110 * (1.5 + 0.75 * max(grid.dims[1], 2) * 2) + 2  # two panels hold a value: two columns
