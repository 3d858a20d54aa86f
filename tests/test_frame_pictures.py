"""A frame's picture as PNG (results/figures.save_frame): the quick writer a search trial uses (OpenCV, zlib's
run-length strategy) and the default one (Pillow) keep the drawn frame's pixels exactly."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from garage_exp.results.figures import draw_boxes, save_frame


@pytest.mark.parametrize("quick", [True, False])
def test_a_saved_frame_holds_the_drawn_pixels(tmp_path, quick):
    rng = np.random.default_rng(4)
    y, x = np.mgrid[0:240, 0:320]
    rgb = np.stack([x * 0.7, y * 0.9, np.full(x.shape, 60.0)], -1) + rng.normal(0, 8, (240, 320, 3))
    rgb = rgb.clip(0, 255).astype(np.uint8)
    rgb[100:140, 50:90] = (200, 30, 30)  # a flat patch, as a painted car's side
    target = SimpleNamespace(kind="vehicle", full_box=(40, 60, 120, 150), visible_box=(50, 70, 110, 140))
    dets = [SimpleNamespace(boxes=[(45, 65, 118, 148)], scores=[0.7], classes=["car"])]
    want = draw_boxes(rgb, target, dets, SimpleNamespace(composite=0.42))
    assert not np.array_equal(want, rgb)  # the boxes and the score drawn
    path = save_frame(tmp_path / "f.png", rgb, target, dets, SimpleNamespace(composite=0.42), quick=quick)
    got = np.asarray(Image.open(path).convert("RGB"))
    assert got.shape == want.shape and np.array_equal(got, want)
