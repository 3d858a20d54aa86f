"""The pedestrian scenario end to end: a child steps out between two parked cars, rendered, detected as a person."""

from __future__ import annotations

import pandas as pd
import pytest
from conftest import run_app

pytestmark = [pytest.mark.render, pytest.mark.detect, pytest.mark.slow]


def test_a_child_hidden_between_cars_is_missed_and_found_once_in_the_lane(tmp_path, mlflow_uri):
    r = run_app(["case=pedestrian", "case.motion.start=-1.0", "case.motion.end=2.0", "case.motion.step=3.0",
                 "case.variants=[{label: child, show: [child, car_left, car_right, car_before1, car_before2],"
                 " target: child}]", "dataset=true", "renderer.save_frames=none", f"tracking.uri={mlflow_uri}"],
                tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    table = pd.read_csv(tmp_path / "run" / "frames.csv")
    hidden, out = table.iloc[0], table.iloc[1]
    assert (hidden.position, out.position) == (-1.0, 2.0)
    assert hidden.visible_fraction < 0.7  # between the cars' noses, the nearer car hides most of the child
    assert out.visible_fraction == 1.0 and out.composite >= 0.5  # in the lane: every model's `person`
    assert out.composite > hidden.composite + 0.3
    labels = (tmp_path / "run" / "dataset" / "labels" / "0001_front.txt").read_text().split("\n")
    assert any(line.startswith("0 ") for line in labels)  # COCO's person
    assert any(line.startswith(("2 ", "7 ")) for line in labels)  # and the parked cars, as cars or trucks
    # The same frame in KITTI: the child a Pedestrian whose 3D box stands on the floor before the camera.
    kitti = (tmp_path / "run" / "dataset" / "kitti" / "label_2" / "000001.txt").read_text().splitlines()
    [child] = [line.split() for line in kitti if line.startswith("Pedestrian ")]
    height, x, y, z = float(child[8]), *map(float, child[11:14])
    assert 1.0 < height < 1.4 and y > 1.0 and z > 2.0 and abs(x) < 3.0
