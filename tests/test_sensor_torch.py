"""The camera model (perception/sensor.py, one implementation) on torch tensors against numpy arrays, on the same
frames: drawing from the same numpy stream, torch frames agree with numpy's to one 8-bit level; blur matches cv2's;
with torch's own stream, the Poisson kind agrees in distribution."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from garage_exp.core.arrays import gaussian_blur
from garage_exp.perception.sensor import make_sensor


def frames(n: int = 3, h: int = 60, w: int = 80) -> np.ndarray:
    """Smooth gradients with a bright and a dark patch: every part of the tone curve is used."""
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:h, 0:w]
    out = np.zeros((n, h, w, 3), np.uint8)
    for i in range(n):
        base = (xx * 3 + yy * 2 + 40 * i) % 256
        out[i] = np.stack([base, (base * 7) % 256, 255 - base], -1)
        out[i, 10:20, 10:30] = 250
        out[i, 40:55, 50:70] = rng.integers(0, 20, (15, 20, 3))
    return out.astype(np.uint8)


@pytest.mark.parametrize("params", [
    {},
    {"blur_sigma": 1.2, "vignetting": 0.35, "tone": "filmic"},
    {"exposure": 0.02, "max_gain": 16.0},  # a dark frame: the gain at its limit
])
def test_camera_kind_agrees_to_one_level_given_the_same_stream(params):
    model = make_sensor(name="camera", kind="camera", params=params)
    pictures = frames()
    want = model.apply_batch(pictures, np.random.default_rng(3))
    got = model.apply_batch(torch.from_numpy(pictures), np.random.default_rng(3)).numpy()
    diff = np.abs(got.astype(int) - want.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 0.002
    # a batch of one is the frame alone
    assert np.array_equal(model.apply(pictures[0], np.random.default_rng(3)),
                          model.apply_batch(pictures[:1], np.random.default_rng(3))[0])


def test_blur_matches_opencv_reflect_border():
    pictures = frames(2).astype(np.float32) / 255
    for sigma in (0.7, 2.0):
        want = np.stack([cv2.GaussianBlur(p, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
                         for p in pictures])
        got = gaussian_blur(torch.from_numpy(pictures), sigma).numpy()
        assert np.abs(got - want).max() < 1e-5


def test_ideal_is_the_frame_and_poisson_kind_agrees_in_distribution():
    pictures = frames()
    assert torch.equal(make_sensor().apply_batch(torch.from_numpy(pictures)), torch.from_numpy(pictures))
    model = make_sensor(name="noisy", kind="noisy", params={"exposure": 0.05})
    want = np.stack([model.apply(p, np.random.default_rng(1)) for p in pictures]).astype(float)
    got = model.apply_batch(torch.from_numpy(pictures), torch.Generator().manual_seed(1)).numpy().astype(float)
    assert abs(got.mean() - want.mean()) < 0.5  # 8-bit levels, over 43,200 noisy values
    assert abs(got.std() - want.std()) < 0.5
    assert not np.array_equal(got, want)  # its own stream: the CPU path keeps numpy's
    same = model.apply_batch(torch.from_numpy(pictures), np.random.default_rng(1)).numpy().astype(int)
    assert np.abs(same - model.apply_batch(pictures, np.random.default_rng(1)).astype(int)).max() <= 1


def test_a_single_frame_is_refused():
    with pytest.raises(ValueError, match=r"\(N, H, W, 3\) uint8"):
        make_sensor().apply_batch(torch.zeros(4, 4, 3, dtype=torch.uint8))
