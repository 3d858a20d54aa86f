"""Ground truth on synthetic frames: no SAPIEN, the id pictures are painted by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from garage_exp.perception.groundtruth import (VehicleTruth, ground_truth, kitti_level, mask_box, occlusion_state,
                                               projected_truncation, world_corners)
from garage_exp.render import Frame
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import Box, CameraSpec, Entity, Material, Pose, Scene

W, H = 640, 480
CAR = (4.5, 1.8, 1.5)
GREY = Material("grey")


def make_frame(ids: np.ndarray, poses: dict[str, Pose], cam_height: float = 0.75) -> Frame:
    """A camera at (0, 0, cam_height) looking along +x, 60 degrees vertical FOV."""
    spec = CameraSpec("front", Pose(0.0, 0.0, cam_height), width=ids.shape[1], height=ids.shape[0])
    return Frame("front", np.zeros((*ids.shape, 3), np.uint8), ids, camera_to_world(Pose(), spec), lens_of(spec),
                 poses)


def car(name: str = "car", pose: Pose = Pose(10.0, 0.0, 0.0, 90.0), role: str = "target") -> Entity:
    return Entity(name, role, pose, extent=CAR, static=False)


def projected_mask(frame: Frame, entity: Entity, pose: Pose) -> np.ndarray:
    """The image rectangle of the vehicle's projected 3D box: a stand-in for its rendered silhouette."""
    uv, depth = frame.project(world_corners(entity, pose))
    assert np.all(depth > 0)
    x1, y1 = np.floor(uv.min(axis=0)).astype(int)
    x2, y2 = np.ceil(uv.max(axis=0)).astype(int)
    mask = np.zeros((frame.height, frame.width), bool)
    mask[max(y1, 0):max(y2, 0), max(x1, 0):max(x2, 0)] = True
    return mask


def truth_for(pose: Pose, hide_columns: int = 0, hide_rows: int = 0) -> VehicleTruth:
    """One car at `pose`; the leftmost `hide_columns` columns (or top rows) of it painted over by a pillar."""
    entity = car(pose=pose)
    frame = make_frame(np.zeros((H, W), np.int32), {"car": pose})
    silhouette = projected_mask(frame, entity, pose)
    frame.ids[silhouette] = 7
    x1, y1, x2, y2 = mask_box(silhouette)
    frame.ids[:, x1:x1 + hide_columns] = 3
    frame.ids[y1:y1 + hide_rows, :] = 3
    [truth] = ground_truth(frame, {"car": silhouette}, Scene("s", [entity]), {"car": 7})
    return truth


def test_mask_box_uses_pixel_edges():
    mask = np.zeros((H, W), bool)
    mask[20:30, 10:20] = True
    assert mask_box(mask) == (10, 20, 20, 30)
    assert mask_box(np.zeros((H, W), bool)) is None


def test_unoccluded_car_ahead_is_easy_and_centred():
    t = truth_for(Pose(10.0, 0.0, 0.0, 90.0))  # side-on width 1.8 m, 10 m ahead
    assert t.visible_fraction == 1.0 and t.occlusion == 0
    assert t.visible_box == t.full_box
    assert t.truncation == pytest.approx(0.0)
    assert t.box_height >= 40 and t.kitti == "easy"
    # The box centre is straight ahead: the image centre.
    assert (t.full_box[0] + t.full_box[2]) / 2 == pytest.approx(W / 2, abs=1)
    # Camera at 0.75 m, box centre at (10, 0, 0.75) after the 3D box's own half height.
    assert t.distance == pytest.approx(10.0, abs=1e-6)


def test_occlusion_lowers_visible_fraction_and_level():
    full = truth_for(Pose(10.0, 0.0, 0.0, 90.0))
    width = full.full_box[2] - full.full_box[0]
    half = truth_for(Pose(10.0, 0.0, 0.0, 90.0), hide_columns=width // 2)
    most = truth_for(Pose(10.0, 0.0, 0.0, 90.0), hide_columns=int(width * 0.8))
    assert half.visible_fraction == pytest.approx(0.5, abs=0.05) and half.kitti == "moderate"
    assert most.visible_fraction == pytest.approx(0.2, abs=0.05) and most.kitti == "hard"
    # The visible box shrinks to the visible part; the full box stays.
    assert half.full_box == full.full_box
    assert half.visible_box[0] > full.full_box[0] and half.visible_box[2] == full.full_box[2]


def test_fully_hidden_vehicle_is_ignored_with_no_visible_box():
    t = truth_for(Pose(10.0, 0.0, 0.0, 90.0), hide_rows=H)
    assert t.visible_pixels == 0 and t.visible_box is None
    assert t.occlusion == 3 and t.kitti == "ignored"


def test_far_car_is_moderate_then_ignored_by_height():
    fy = lens_of(CameraSpec("c", Pose(), width=W, height=H)).fy
    # The side-on car's near face (0.9 m nearer than its centre) sets the projected height.
    moderate = truth_for(Pose(fy * CAR[2] / 32 + 0.9, 0.0, 0.0, 90.0))
    ignored = truth_for(Pose(fy * CAR[2] / 20 + 0.9, 0.0, 0.0, 90.0))
    assert 25 <= moderate.box_height < 40 and moderate.kitti == "moderate"
    assert ignored.box_height < 25 and ignored.kitti == "ignored"


def test_truncation_of_a_car_half_out_of_the_image():
    # Put the side-on car's centre on the right image border: half its projected box is outside.
    fx = lens_of(CameraSpec("c", Pose(), width=W, height=H)).fx
    d = 12.0
    y = -(W / 2) / fx * d
    t = truth_for(Pose(d, y, 0.0, 90.0))
    # Not exactly 0.5: the near face projects wider than the far one and spills further out.
    assert t.truncation == pytest.approx(0.5, abs=0.06)
    assert t.full_box[2] == W  # the full box is clipped to the image
    inward = truth_for(Pose(d, y + 0.6, 0.0, 90.0))
    assert 0.3 < inward.truncation < t.truncation
    assert inward.kitti == "hard" and t.kitti == "ignored"


def test_truncation_behind_and_straddling_the_camera():
    entity = car()
    frame = make_frame(np.zeros((H, W), np.int32), {})
    behind = world_corners(entity, Pose(-10.0, 0.0, 0.0))
    assert projected_truncation(frame, behind) == 1.0
    beside = world_corners(entity, Pose(0.5, 2.0, 0.0))  # the car's rear is behind the camera, nose ahead
    assert projected_truncation(frame, beside) > 0.5


def test_vehicles_out_of_view_are_left_out_and_order_is_kept():
    a, b = car("a"), car("b", Pose(15.0, 3.0, 0.0, 0.0))
    frame = make_frame(np.zeros((H, W), np.int32), {"a": a.pose, "b": b.pose})
    sa, sb = projected_mask(frame, a, a.pose), projected_mask(frame, b, b.pose)
    frame.ids[sb] = 2
    frame.ids[sa] = 1  # a is nearer and hides part of b
    truth = ground_truth(frame, {"b": sb, "a": sa, "gone": np.zeros((H, W), bool)}, Scene("s", [a, b, car("gone")]),
                         {"a": 1, "b": 2, "gone": 3})
    assert [t.name for t in truth] == ["b", "a"]
    tb, ta = truth
    assert ta.visible_fraction == 1.0
    assert 0.0 < tb.visible_fraction < 1.0
    assert tb.visible_pixels == int(((frame.ids == 2) & sb).sum())


def test_box_shapes_stand_in_for_a_missing_extent():
    entity = Entity("t", "target", Pose(10.0, 0.0, 0.0), [Box((2.0, 2.0, 2.0), GREY, Pose(0, 0, 1.0))], static=False)
    corners = world_corners(entity, entity.pose)
    assert corners.min(axis=0) == pytest.approx([9.0, -1.0, 0.0])
    assert corners.max(axis=0) == pytest.approx([11.0, 1.0, 2.0])


def test_silhouette_of_the_wrong_size_is_an_error():
    frame = make_frame(np.zeros((H, W), np.int32), {})
    with pytest.raises(ValueError):
        ground_truth(frame, {"car": np.ones((10, 10), bool)}, Scene("s", [car()]), {"car": 1})


@pytest.mark.parametrize("height, fraction, truncation, level", [
    (40, 0.85, 0.15, "easy"),
    (39, 1.0, 0.0, "moderate"),
    (40, 0.84, 0.0, "moderate"),
    (40, 1.0, 0.16, "moderate"),
    (25, 0.5, 0.30, "moderate"),
    (25, 0.49, 0.0, "hard"),
    (25, 1.0, 0.31, "hard"),
    (25, 0.01, 0.50, "hard"),
    (24, 1.0, 0.0, "ignored"),
    (100, 1.0, 0.51, "ignored"),
    (100, 0.0, 0.0, "ignored"),
])
def test_kitti_levels(height, fraction, truncation, level):
    assert kitti_level(height, fraction, truncation) == level


def test_occlusion_states():
    assert [occlusion_state(f) for f in (1.0, 0.85, 0.7, 0.5, 0.3, 0.0)] == [0, 0, 1, 1, 2, 3]


def test_camera_pose_yaw_and_pitch():
    spec = CameraSpec("c", Pose(1.0, 0.0, 1.5, 90.0), pitch=30.0)
    pose = camera_to_world(Pose(5.0, 5.0, 0.0, 90.0), spec)
    # Ego at (5, 5) facing +y; the mount 1 m ahead is (5, 6); mount yaw 90 turns the camera to -x.
    assert pose[:3, 3] == pytest.approx([5.0, 6.0, 1.5])
    forward = pose[:3, 0]
    assert forward == pytest.approx([-math.cos(math.radians(30)), 0.0, -math.sin(math.radians(30))], abs=1e-9)
    assert pose[:3, 2][2] > 0  # the camera's up still points upwards


@settings(max_examples=40, deadline=None)
@given(x=st.floats(3.0, 40.0), y=st.floats(-15.0, 15.0), yaw=st.floats(0.0, 360.0),
       hidden=st.integers(0, W))
def test_truth_invariants(x, y, yaw, hidden):
    entity = car(pose=Pose(x, y, 0.0, yaw))
    frame = make_frame(np.zeros((H, W), np.int32), {"car": entity.pose})
    silhouette = projected_mask(frame, entity, entity.pose)
    frame.ids[silhouette] = 5
    frame.ids[:, :hidden] = 1
    truth = ground_truth(frame, {"car": silhouette}, Scene("s", [entity]), {"car": 5})
    if not silhouette.any():
        assert truth == []
        return
    [t] = truth
    assert 0.0 <= t.visible_fraction <= 1.0 and 0.0 <= t.truncation <= 1.0
    x1, y1, x2, y2 = t.full_box
    assert 0 <= x1 < x2 <= W and 0 <= y1 < y2 <= H
    if t.visible_box is not None:
        vx1, vy1, vx2, vy2 = t.visible_box
        assert x1 <= vx1 < vx2 <= x2 and y1 <= vy1 < vy2 <= y2
    assert t.kitti in ("easy", "moderate", "hard", "ignored")


def test_truncation_at_the_top_border_depends_on_the_camera_height():
    """A side-on car raised so that its box's centre row sits on the top border: about half of it outside.
    The camera's own height (0.75 m) counts: the same car seen from 2.75 m is almost all in view."""
    frame = make_frame(np.zeros((H, W), np.int32), {})
    d = 8.0
    centre_z = 0.75 + (H / 2) / frame.lens.fy * d  # the car's box centre on the top image row
    corners = world_corners(car(), Pose(d, 0.0, centre_z - CAR[2] / 2, 90.0))
    at_border = projected_truncation(frame, corners)
    assert at_border == pytest.approx(0.5, abs=0.08)
    assert projected_truncation(make_frame(np.zeros((H, W), np.int32), {}, cam_height=2.75), corners) < 0.1
    assert projected_truncation(frame, world_corners(car(), Pose(d, 0.0, 0.0, 90.0))) == 0.0  # all in view
    wholly_above = world_corners(car(), Pose(d, 0.0, centre_z + 3.0, 90.0))
    assert projected_truncation(frame, wholly_above) == 1.0  # clipped to 1, not above


# --- what hides the target (`occluder`): the category covering most of its hidden pixels, from the id picture ---

PILLAR, PARKED, WALKER, WALL, SHADOW, TARGET = 3, 9, 11, 4, 6, 7


def occluder_of(paint: dict[int, float], pose: Pose = Pose(10.0, 0.0, 0.0, 90.0)) -> VehicleTruth:
    """The target at `pose` with, from its left edge on, `paint`'s ids painted over that share of its columns
    each: a merged pillar body (Frame.pillars), a parked car and a person (their own ids, by their entities), a
    wall (an id nothing names: structure), a contact shadow (a decal) or 0 (nothing drawn)."""
    target = car("car", pose)
    frame = make_frame(np.zeros((H, W), np.int32), {"car": pose})
    frame.pillars, frame.see_through = frozenset({PILLAR}), frozenset({SHADOW})
    silhouette = projected_mask(frame, target, pose)
    frame.ids[silhouette] = TARGET
    x1, _, x2, _ = mask_box(silhouette)
    at = x1
    for i, share in paint.items():
        columns = int(round(share * (x2 - x1)))
        frame.ids[:, at:at + columns] = i
        at += columns
    scene = Scene("s", [target, car("parked", Pose(5.0, 0.0, 0.0, 90.0), role="parked"),
                        Entity("walker", "moving", Pose(4.0, 0.0, 0.0), extent=(0.3, 0.5, 1.7), static=False,
                               kind="person")])
    [truth] = ground_truth(frame, {"car": silhouette}, scene, {"car": TARGET, "parked": PARKED, "walker": WALKER})
    return truth


def test_the_occluder_is_what_covers_most_of_the_hidden_pixels():
    assert occluder_of({PILLAR: 0.3, PARKED: 0.1}).occluder == "pillar"
    assert occluder_of({PILLAR: 0.1, PARKED: 0.4}).occluder == "vehicle"
    assert occluder_of({WALKER: 0.2, PILLAR: 0.1}).occluder == "person"
    assert occluder_of({WALL: 0.3, PILLAR: 0.2}).occluder == "structure"  # an id nothing names: the building
    assert occluder_of({}).occluder == "none"


def test_nothing_hides_a_target_under_two_percent_hidden_or_cut_by_the_border_or_a_decal():
    assert occluder_of({PILLAR: 0.01}).occluder == "none"  # under MIN_HIDDEN of its silhouette
    assert occluder_of({PILLAR: 0.05}).occluder == "pillar"
    assert occluder_of({SHADOW: 0.5, 0: 0.3}).occluder == "none"  # a decal and nothing drawn hide nothing
    # half of it outside the image, nothing in the way: truncated, not hidden
    fx = lens_of(CameraSpec("c", Pose(), width=W, height=H)).fx
    cut = occluder_of({}, Pose(12.0, -(W / 2) / fx * 12.0, 0.0, 90.0))
    assert cut.truncation > 0.4 and cut.visible_fraction == 1.0 and cut.occluder == "none"


def test_a_pillar_with_its_own_id_is_a_pillar_and_a_box_occluder_is_structure():
    from garage_exp.perception.groundtruth import occluder_ids

    frame = make_frame(np.zeros((H, W), np.int32), {})
    frame.pillars = frozenset({40})
    scene = Scene("s", [Entity("pillar_1_2", "structure", Pose()), Entity("wall_N_0", "structure", Pose()),
                        car("ego", role="ego"), Entity("crate", "occluder", Pose(), extent=(1, 1, 1), kind="box"),
                        Entity("kid", "target", Pose(), extent=(0.3, 0.4, 1.2), kind="person")])
    got = occluder_ids(frame, scene, {"pillar_1_2": 5, "wall_N_0": 6, "ego": 7, "crate": 8, "kid": 9, "old": 10})
    assert got == {"pillar": [5, 40], "vehicle": [7], "person": [9]}  # the wall, the crate, the unknown: structure


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 3), st.integers(1, 6), st.integers(0, 2**32 - 1))
def test_hidden_pixels_counted_per_category_as_the_product_counts_them(frames, actors, seed):
    """hidden_by on the CPU counts by bincount; each count equals the pixels an actor has hidden behind ids of
    that category (the product's definition): named ids, structure (any other drawn id, ids past the named
    ones included), id 0 hiding nothing."""
    from garage_exp.perception.groundtruth import OCCLUDERS, hidden_by

    rng = np.random.default_rng(seed)
    ids = rng.integers(0, 40, (frames, 12, 16)).astype(np.int32)
    hidden = rng.random((frames, actors, 12, 16)) < rng.random()
    occluders = {"pillar": [3, 4], "vehicle": [7, 9, 11], "person": [20]}
    got = hidden_by(ids, hidden, occluders)
    category = np.full(ids.shape, len(OCCLUDERS) - 1)  # structure
    for c, name in enumerate(OCCLUDERS[:-1]):
        category[np.isin(ids, occluders[name])] = c
    category[ids == 0] = -1
    want = np.array([[[int((hidden[n, k] & (category[n] == c)).sum()) for c in range(len(OCCLUDERS))]
                      for k in range(actors)] for n in range(frames)])
    assert got.shape == want.shape and np.array_equal(got, want)
