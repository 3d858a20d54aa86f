"""Slot ground truth (issue 25) on the tiny plan's scene description, no rendering: the bays' corners on the painted
lines, marking points shared between neighbours, T and L, occupancy, and each corner's visibility in the BEV."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import compose_cfg

from garage_exp.slots.truth import (VISIBILITY, Obstacle, WorldBay, obstacles, paint_left, slot_truth,
                                                texture_left, world_bays)
from garage_exp.render.bev import bev_maps
from garage_exp.scene.schema import BevSpec
from garage_exp.scene.description import Pose
from garage_exp.scene.markings import unit_hash

SLOTS = ("plan=tiny", "camera=fisheye4", "case=slots", "case.motion.start=3.0", "case.motion.end=4.0",
         "case.motion.step=1.0")


@pytest.fixture(scope="module")
def job():
    from garage_exp.run.preflight import preflight

    cfg = compose_cfg(*SLOTS)
    prepared = preflight(cfg, check_space=False)
    return cfg, prepared


def truth_of(job, shot=0, wear=0.0, extra=()):
    cfg, prepared = job
    scene, setup = prepared.scene, prepared.setup
    spec = BevSpec()
    ego = next(v for v in scene.vehicles() if v.role == "ego")
    maps = bev_maps(scene.cameras, spec, ego.extent)
    world = world_bays(prepared.classified, cfg.garage, wear)
    s = setup.shots[shot]
    return world, slot_truth(world, spec, s.ego, scene.cameras, maps, obstacles(scene, s.poses) + list(extra)), s


def test_bays_have_their_corners_on_the_painted_lines(job):
    cfg, prepared = job
    world = world_bays(prepared.classified, cfg.garage)
    assert len(world) == 12  # tiny: a bay per 2.6 m cell, two in each 5-6 m one
    half = cfg.garage.marking_width / 2
    by = {b.bay: b for b in world}
    # bay_0_0_0 (row 0, column 0; x 0-2.6, y 16-21, facing S onto the lane at y = 16): its lines are the cell's
    # edges moved in by half a line; the line it shares with bay_0_1_0 is drawn by that cell, moved into it
    b = by["bay_0_0_0"]
    xs = sorted({round(c[0], 6) for c in b.corners})
    assert xs == pytest.approx([half, 2.6 + half])
    assert b.corners[0][1] == b.corners[1][1] == pytest.approx(16.0)  # the entrance on the lane's edge
    assert b.corners[2][1] == b.corners[3][1] == pytest.approx(21.0)
    assert b.into == pytest.approx(90.0)
    # p1 -> p2 has the bay on its right (seen from above): walking west along y = 16 with the bay to the north
    assert b.corners[0][0] > b.corners[1][0]
    assert b.shapes == ("T", "L")  # a bay continues east of it (bay_0_1_0); the row ends at the west wall
    for bay in world:  # rectangles a bay wide (2.4-3 m: a 6 m cell holds two) and a cell deep (5 m; column 3: 2.6)
        c = np.array(bay.corners)
        assert np.linalg.norm(c[0] - c[1]) == pytest.approx(np.linalg.norm(c[3] - c[2]))
        depth = np.linalg.norm(c[1] - c[2])
        assert 2.4 < np.linalg.norm(c[0] - c[1]) < 3.0 and depth in (pytest.approx(5.0), pytest.approx(2.6))


def test_wear_takes_the_pieces_the_markings_remove_and_fades_the_rest():
    assert paint_left(0, 0, 0, 0.0) == 1.0 and paint_left(0, 0, 0, 1.0) == 0.0
    gone = [(i, j, m) for i in range(4) for j in range(4) for m in range(3) if unit_hash(i, j, m) < 0.3]
    kept = [(i, j, m) for i in range(4) for j in range(4) for m in range(3) if unit_hash(i, j, m) >= 0.3]
    assert gone and kept
    assert all(paint_left(*k, 0.6) == 0.0 for k in gone)
    assert all(paint_left(*k, 0.6) == pytest.approx(0.4) for k in kept)
    # the real look's paint texture wears patches through: little at the worn materials' 0.35, half at 0.8
    assert texture_left(0.0) == 1.0 and 0.9 < texture_left(0.35) < 1.0 and 0.4 < texture_left(0.8) < 0.6


def test_the_worn_level_leaves_every_bay_line_worn_and_the_fresh_one_none(job):
    cfg, prepared = job
    fresh = world_bays(prepared.classified, cfg.garage, 0.0, 0.35)  # look=real: materials=worn's own paint wear
    worn = world_bays(prepared.classified, cfg.garage, 0.7, 0.805)  # wear=worn on top of it
    assert min(p for b in fresh for p in b.paint) > 0.9
    assert max(p for b in worn for p in b.paint) < 0.25  # WORN: every corner's paint counts as worn


def test_slot_truth_in_the_bev(job):
    world, truth, shot = truth_of(job)
    frame = truth.frame
    assert frame.size == (600, 400) and frame.meters_per_pixel == 0.03
    bays = [s.bay for s in frame.slots]
    assert len(bays) >= 4 and len(set(bays)) == len(bays)
    occupied = {s.bay for s in frame.slots if s.occupied}
    # the case's car stands in its bay 1 (bay_2_0_0 on the tiny plan), the other car in bay 4 (bay_0_2_0)
    assert occupied == {"bay_2_0_0", "bay_0_2_0"} & set(bays) and "bay_2_0_0" in occupied
    for slot in frame.slots:
        p1, p2 = frame.points[slot.p1], frame.points[slot.p2]
        assert (p1.x, p1.y) == pytest.approx(slot.corners[0]) and (p2.x, p2.y) == pytest.approx(slot.corners[1])
        # the direction runs from the entrance to the back, into the slot
        back = np.subtract(slot.corners[3], slot.corners[0])
        assert back / np.linalg.norm(back) == pytest.approx([math.cos(p1.direction), math.sin(p1.direction)])
    # neighbouring bays share their marking point (bay_0_0_0's east line is bay_0_1_0's west line)
    index = {s.bay: s for s in frame.slots}
    if "bay_0_0_0" in index and "bay_0_1_0" in index:
        a, b = index["bay_0_0_0"], index["bay_0_1_0"]
        assert {a.p1, a.p2} & {b.p1, b.p2}
    # every corner inside the BEV has a visibility and its pixel in some camera
    for vis, cams, slot in zip(truth.visibility, truth.in_cameras, frame.slots):
        for k, v in enumerate(vis):
            x, y = slot.corners[k]
            inside = 0 <= x < 600 and 0 <= y < 400
            assert v in VISIBILITY and (inside or v == "outside")
            if v == "visible":
                assert any(cams[c][k] is not None for c in cams)
    assert any(truth.fair) and truth.to_dict()["slots"][0]["bay"] == frame.slots[0].bay


def test_a_box_on_a_corner_hides_it_and_worn_paint_shows_as_worn(job):
    world, truth, shot = truth_of(job)
    k, corner = next((n, c) for n, vis in enumerate(truth.visibility) for c, v in enumerate(vis[:2])
                     if v == "visible" and truth.fair[n])
    bay = next(b for b in world if b.bay == truth.frame.slots[k].bay)
    x, y = bay.corners[corner]
    box = Obstacle("box", "box", Pose(x, y, 0.0, 0.0), (0.3, 0.3), 1.0)
    _, hidden, _ = truth_of(job, extra=[box])
    assert hidden.visibility[k][corner] == "hidden" and not hidden.fair[k]
    _, worn, _ = truth_of(job, wear=1.0)
    assert all(v in ("worn", "hidden", "outside") for vis in worn.visibility for v in vis)
    assert worn.fair == truth.fair  # worn paint makes a slot hard, not unfair


def test_corners_under_the_ego_or_off_the_bev_are_outside(job):
    world, _, shot = truth_of(job)
    cfg, prepared = job
    ego = shot.ego
    fake = WorldBay("under", ((ego.x - 0.5, ego.y), (ego.x + 0.5, ego.y), (ego.x + 0.5, ego.y + 30.0),
                              (ego.x - 0.5, ego.y + 30.0)), 90.0, ("L", "L"), (1.0, 1.0, 1.0, 1.0))
    spec = BevSpec()
    scene = prepared.scene
    maps = bev_maps(scene.cameras, spec, next(v for v in scene.vehicles() if v.role == "ego").extent)
    truth = slot_truth([fake], spec, ego, scene.cameras, maps, [])
    assert truth.visibility[0][0] == "outside" and truth.visibility[0][1] == "outside"  # under the body
    assert truth.visibility[0][2] == "outside" and truth.visibility[0][3] == "outside"  # 30 m away
    assert truth.fair == [False]
