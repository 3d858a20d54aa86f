"""The slot exports (issue 25) read back: the PS2.0-like labels and the COCO keypoints give the SlotFrame written,
on hand-made truth; the exports entry point draws a slot export."""

from __future__ import annotations

import json

import numpy as np
import pytest

from garage_exp.core.errors import GarageError
from garage_exp.slots.export import SlotExports, read_coco_keypoints, read_ps2
from garage_exp.slots.marks import MarkingPoint, Slot, SlotFrame
from garage_exp.slots.truth import SlotTruth


def hand_made() -> SlotTruth:
    """Two bays side by side sharing a T point, the second's far point an L; one corner hidden, one off-image."""
    down = np.pi / 2
    points = [MarkingPoint(100.0, 50.0, down, "L"), MarkingPoint(180.0, 50.0, down, "T"),
              MarkingPoint(260.0, 50.0, down, "L")]
    slots = [Slot(1, 0, ((180.0, 50.0), (100.0, 50.0), (100.0, 240.0), (180.0, 216.0)), False, bay="bay_0_0_0"),
             Slot(2, 1, ((260.0, 50.0), (180.0, 50.0), (180.0, 216.0), (260.0, 216.0)), True, bay="bay_0_0_1")]
    frame = SlotFrame(points, slots, 0.03, (300, 230))
    return SlotTruth(frame, [("visible", "worn", "outside", "visible"), ("visible", "visible", "hidden", "hidden")],
                     [{"front": [(1.0, 2.0), None, None, None]}, {"front": [None] * 4}])


def test_ps2_and_coco_keypoints_read_back(tmp_path):
    truth = hand_made()
    out = SlotExports(tmp_path / "slots")
    image = out.add("0000_bev", np.zeros((230, 300, 3), np.uint8), truth)
    root = out.finish()
    assert image.exists() and (root / "truth" / "0000_bev.json").exists()
    ps2 = json.loads((root / "ps2" / "0000_bev.json").read_text())
    assert ps2["marks"][0] == [100.0, 50.0, pytest.approx(np.pi / 2), 1]  # an L
    assert ps2["slots"] == [[2, 1, 0], [3, 2, 1]]  # 1-based, as PS2.0's .mat files
    back = read_ps2(root / "ps2" / "0000_bev.json")
    assert back == truth.frame
    coco = json.loads((root / "coco_keypoints.json").read_text())
    assert coco["categories"][0]["name"] == "parking_slot" and len(coco["annotations"]) == 2
    flags = [a["keypoints"][2::3] for a in coco["annotations"]]
    assert flags == [[2, 2, 0, 2], [2, 2, 1, 1]]  # worn paint is seen; off the image 0; hidden 1
    frames = read_coco_keypoints(root / "coco_keypoints.json")
    got = frames["0000_bev.png"]
    assert got.size == (300, 230) and got.meters_per_pixel == 0.03
    assert [s.corners for s in got.slots] == [s.corners for s in truth.frame.slots]
    assert [(s.occupied, s.bay) for s in got.slots] == [(False, "bay_0_0_0"), (True, "bay_0_0_1")]
    # the shared T point is one marking point again
    assert len(got.points) == 3 and got.slots[0].p1 == got.slots[1].p2
    assert [p.shape for p in got.points] == ["T", "L", "L"]


def test_a_broken_label_file_is_one_line(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"marks": [[1, 2]], "slots": []}))
    with pytest.raises(GarageError, match="bad.json"):
        read_ps2(bad)
    bad.write_text("{")
    with pytest.raises(GarageError, match="bad.json"):
        read_coco_keypoints(bad)


def test_the_exports_entry_point_draws_a_slot_export(tmp_path):
    from garage_exp.exports.__main__ import main

    out = SlotExports(tmp_path / "slots")
    out.add("0000_bev", np.full((230, 300, 3), 90, np.uint8), hand_made())
    out.finish()
    png = tmp_path / "drawn.png"
    assert main([str(tmp_path / "slots"), "-o", str(png)]) == 0
    from PIL import Image

    drawn = np.asarray(Image.open(png))
    assert drawn.shape == (230, 300, 3) and (drawn != 90).any()
