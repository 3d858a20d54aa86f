"""PS2.0 slot metrics (garage_exp/slots/results.py) on hand-made frames: no images, no rendering."""

import math
from dataclasses import replace

import pytest

from garage_exp.slots.schema import SlotMetricsConf
from garage_exp.slots.marks import MarkingPoint, Slot, SlotFrame
from garage_exp.slots.results import pool, score

MPP = 0.02  # 0.17 m tolerance = 8.5 px
DOWN = math.pi / 2  # into the slots: rows grow downwards
CONF = SlotMetricsConf()


def row(xs=(100.0, 225.0, 350.0), occupied=(False, True), mpp=MPP) -> SlotFrame:
    """Two bays side by side, entrance along row 200, 5.3 m deep."""
    points = [MarkingPoint(x, 200.0, DOWN) for x in xs]
    depth = 5.3 / mpp
    slots = [Slot(k, k + 1, ((xs[k], 200.0), (xs[k + 1], 200.0), (xs[k + 1], 200.0 + depth), (xs[k], 200.0 + depth)),
                  occupied=occ) for k, occ in enumerate(occupied)]
    return SlotFrame(points, slots, mpp, (500, 500))


def moved(frame: SlotFrame, k: int, dx: float = 0.0, turn_deg: float = 0.0) -> SlotFrame:
    """Point k moved dx pixels along the row and turned; the slots' corners follow their points."""
    points = list(frame.points)
    q = points[k]
    points[k] = replace(q, x=q.x + dx, direction=q.direction + math.radians(turn_deg))
    slots = []
    for s in frame.slots:
        c = list(s.corners)
        c[0] = (points[s.p1].x, points[s.p1].y)
        c[1] = (points[s.p2].x, points[s.p2].y)
        slots.append(replace(s, corners=tuple(c)))
    return SlotFrame(points, slots, frame.meters_per_pixel, frame.size)


def test_a_perfect_detection_scores_one():
    m = score(row(), row(), None, CONF)
    assert (m["point_tp"], m["point_fp"], m["point_fn"]) == (3, 0, 0)
    assert (m["slot_tp"], m["slot_fp"], m["slot_fn"]) == (2, 0, 0)
    assert m["point_precision"] == m["point_recall"] == m["slot_precision"] == m["slot_recall"] == 1.0
    assert m["occupancy_accuracy"] == 1.0 and m["occupancy_n"] == 2
    assert m["point_error_m"] == 0.0 and m["point_angle_deg"] == 0.0


def test_one_missed_point_and_its_slot():
    truth = row()
    found = SlotFrame(truth.points[:2], truth.slots[:1], MPP, truth.size)
    m = score(truth, found, None, CONF)
    assert (m["point_tp"], m["point_fp"], m["point_fn"]) == (2, 0, 1)
    assert m["point_recall"] == pytest.approx(2 / 3) and m["point_precision"] == 1.0
    assert (m["slot_tp"], m["slot_fn"]) == (1, 1) and m["slot_recall"] == 0.5


@pytest.mark.parametrize("metres, hit", [(0.165, True), (0.175, False)])
def test_a_shifted_point_matches_only_within_the_tolerance(metres, hit):
    m = score(row(), moved(row(), 1, dx=metres / MPP), None, CONF)
    assert m["point_tp"] == (3 if hit else 2)
    assert (m["point_fp"], m["point_fn"]) == ((0, 0) if hit else (1, 1))
    assert m["slot_tp"] == (2 if hit else 0)  # both slots share the moved point
    if hit:
        assert m["point_error_m"] == pytest.approx(metres / 3)


@pytest.mark.parametrize("turn, hit", [(29.0, True), (31.0, False), (180.0, False)])
def test_a_point_facing_the_wrong_way_does_not_match(turn, hit):
    m = score(row(), moved(row(), 0, turn_deg=turn), None, CONF)
    assert (m["point_tp"], m["point_fn"]) == ((3, 0) if hit else (2, 1))
    assert m["slot_tp"] == 2  # slots match on their entrance points' places alone, as PS2.0's do


def test_a_false_slot_lowers_slot_precision_only():
    truth = row()
    extra = Slot(0, 2, ((100.0, 200.0), (350.0, 200.0), (350.0, 465.0), (100.0, 465.0)))
    m = score(truth, SlotFrame(truth.points, truth.slots + [extra], MPP, truth.size), None, CONF)
    assert (m["slot_tp"], m["slot_fp"], m["slot_fn"]) == (2, 1, 0)
    assert m["slot_precision"] == pytest.approx(2 / 3) and m["point_precision"] == 1.0


def test_a_slot_opening_to_the_other_side_is_false():
    truth = row()
    s = truth.slots[0]
    (a, b, _, _) = s.corners
    flipped = replace(s, corners=(a, b, (b[0], 200.0 - 265.0), (a[0], 200.0 - 265.0)))
    m = score(truth, SlotFrame(truth.points, [flipped, truth.slots[1]], MPP, truth.size), None, CONF)
    assert (m["slot_tp"], m["slot_fp"], m["slot_fn"]) == (1, 1, 1)


def test_entrance_points_match_in_either_order():
    truth = row()
    s = truth.slots[0]
    swapped = Slot(s.p2, s.p1, (s.corners[1], s.corners[0], s.corners[3], s.corners[2]), s.occupied)
    m = score(truth, SlotFrame(truth.points, [swapped, truth.slots[1]], MPP, truth.size), None, CONF)
    assert m["slot_tp"] == 2


def test_an_unfair_slot_is_neither_missed_nor_false():
    truth = row()
    missed = SlotFrame(truth.points[:2], truth.slots[:1], MPP, truth.size)
    m = score(truth, missed, [True, False], CONF)  # slot 1 (and point 2, which opens only it) unseen
    assert (m["point_tp"], m["point_fn"], m["slot_tp"], m["slot_fn"]) == (2, 0, 1, 0)
    m = score(truth, truth, [True, False], CONF)  # found anyway: not counted either way
    assert (m["point_tp"], m["point_fp"], m["slot_tp"], m["slot_fp"]) == (2, 0, 1, 0)
    m = score(truth, SlotFrame(truth.points[:2], truth.slots[:1], MPP, truth.size), [False, True], CONF)
    assert (m["point_fn"], m["slot_fn"]) == (1, 1)  # point 1 opens a fair slot too: still counted


def test_a_truth_point_outside_the_image_is_not_missed():
    truth = row(xs=(100.0, 225.0, 510.0))
    found = SlotFrame(truth.points[:2], truth.slots[:1], MPP, truth.size)
    m = score(truth, found, None, CONF)
    assert (m["point_tp"], m["point_fn"]) == (2, 0)


def test_occupancy_right_wrong_and_undecided():
    truth = row(occupied=(False, True))
    m = score(truth, row(occupied=(True, True)), None, CONF)
    assert (m["occupancy_right"], m["occupancy_n"], m["occupancy_accuracy"]) == (1, 2, 0.5)
    m = score(truth, row(occupied=(None, True)), None, CONF)
    assert (m["occupancy_right"], m["occupancy_n"]) == (1, 1)


def test_each_truth_point_matches_once():
    truth = row()
    twin = replace(truth.points[0], x=truth.points[0].x + 2, score=0.9)
    m = score(truth, SlotFrame(truth.points + [twin], truth.slots, MPP, truth.size), None, CONF)
    assert (m["point_tp"], m["point_fp"]) == (3, 1)


def test_low_scores_are_dropped_and_a_coarser_detector_is_rescaled():
    truth = row()
    weak = SlotFrame([replace(q, score=0.2) for q in truth.points], truth.slots, MPP, truth.size)
    m = score(truth, weak, None, replace(CONF, min_score=0.5))
    assert (m["point_tp"], m["point_fn"]) == (0, 3)
    half = SlotFrame([replace(q, x=q.x / 2, y=q.y / 2) for q in truth.points],
                     [replace(s, corners=tuple((x / 2, y / 2) for x, y in s.corners)) for s in truth.slots],
                     2 * MPP, (250, 250))
    m = score(truth, half, None, CONF)
    assert (m["point_tp"], m["slot_tp"]) == (3, 2)


def test_nothing_to_find_and_nothing_found_gives_nan_rates():
    m = score(SlotFrame(), SlotFrame(), None, CONF)
    assert math.isnan(m["point_precision"]) and math.isnan(m["slot_recall"])


def test_pooling_sums_counts_and_recomputes_rates():
    truth = row()
    a = score(truth, truth, None, CONF)  # 3 tp
    extra = [MarkingPoint(400.0 + 20 * k, 300.0, DOWN) for k in range(3)]
    b = score(truth, SlotFrame(truth.points[:1] + extra, [], MPP, truth.size), None, CONF)  # 1 tp, 3 fp, 2 fn
    both = pool([a, b])
    assert (both["point_tp"], both["point_fp"], both["point_fn"]) == (4, 3, 2)
    assert both["point_precision"] == pytest.approx(4 / 7)  # not the mean of 1 and 1/4
    assert both["point_recall"] == pytest.approx(4 / 6)
    assert both["slot_recall"] == pytest.approx(2 / 4)


def test_fair_must_cover_every_truth_slot():
    with pytest.raises(ValueError, match="fair has 1 entries for 2"):
        score(row(), row(), [True], CONF)
