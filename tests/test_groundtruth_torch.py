"""Ground truth's pixel work (perception/groundtruth.py, one implementation) on a batch of torch tensors against
numpy, frame by frame: the same pixel counts, boxes and records, to the pixel, on the same inputs (CPU tensors)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_groundtruth import car, make_frame

from garage_exp.perception.groundtruth import batch_mask_stats, mask_box, mask_boxes, mask_stats, stats_of, truth_records
from garage_exp.scene.description import Entity, Pose, Scene

H, W = 48, 64


def blobs(rng: np.random.Generator, k: int) -> np.ndarray:
    """k random silhouettes: rectangles with holes, some touching the border, one empty."""
    out = np.zeros((k, H, W), bool)
    for i in range(k - 1):
        x1, y1 = rng.integers(-5, W - 2), rng.integers(-5, H - 2)
        x2, y2 = x1 + rng.integers(1, 30), y1 + rng.integers(1, 25)
        out[i, max(y1, 0):y2, max(x1, 0):x2] = True
        out[i] &= rng.random((H, W)) > 0.2
    return out


def random_frames(seed: int, n: int = 5, k: int = 4):
    rng = np.random.default_rng(seed)
    names = [f"car{i}" for i in range(k)]
    frames, silhouettes = [], []
    for _ in range(n):
        ids = rng.integers(0, k + 3, (H, W)).astype(np.int32)  # actors are 1..k, 5 a decal, others scenery
        frame = make_frame(ids, {m: Pose(8.0 + 3 * i, i - 1.5, 0.0, 90.0) for i, m in enumerate(names)})
        frame.see_through = frozenset({k + 1}) if seed % 2 else frozenset()
        frames.append(frame)
        silhouettes.append(blobs(rng, k))
    return names, frames, silhouettes


def test_mask_boxes_match_numpy_to_the_pixel():
    rng = np.random.default_rng(0)
    masks = blobs(rng, 12)
    boxes, empty = mask_boxes(torch.from_numpy(masks))
    for m, box, e in zip(masks, boxes.tolist(), empty.tolist()):
        assert (None if e else tuple(box)) == mask_box(m)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_batched_stats_and_records_equal_the_numpy_ones(seed):
    names, frames, silhouettes = random_frames(seed)
    ids = {m: i + 1 for i, m in enumerate(names)}
    see = sorted(frames[0].see_through)
    # what hides each actor, counted per category: 1-2 vehicles, 3 a person, 6 a pillar, 0 nothing, others structure
    occluders = {"pillar": [6], "vehicle": [1, 2], "person": [3]}
    batch = batch_mask_stats(torch.from_numpy(np.stack([f.ids for f in frames])),
                             torch.from_numpy(np.stack(silhouettes)),
                             torch.tensor([[ids[m] for m in names]] * len(frames), dtype=torch.int32), see, occluders)
    got = stats_of(batch, [names] * len(frames))
    # car0 has no extent: its truncation comes from the silhouette touching the border
    scene = Scene("s", [Entity(names[0], "target", Pose(), static=False)]
                  + [car(m, Pose(8.0, 0.0, 0.0, 90.0)) for m in names[1:]])
    for frame, sil, stats in zip(frames, silhouettes, got):
        want = mask_stats(frame, dict(zip(names, sil)), ids, occluders)
        assert stats == want
        assert all(len(s.hidden_by) == 4 for s in want if s.full_box) and any(sum(s.hidden_by) for s in want)
        tensors = {m: torch.from_numpy(x) for m, x in zip(names, sil)}
        frame_t = make_frame(torch.from_numpy(frame.ids), frame.poses)
        frame_t.see_through = frame.see_through
        assert mask_stats(frame_t, tensors, ids, occluders) == want  # one frame, torch
        assert truth_records(frame, stats, scene) == truth_records(frame, want, scene)
    assert any(s.full_box is None for s in got[0])  # the empty silhouette is there, and gives no record


def test_padding_beyond_a_frames_actors_is_dropped():
    names, frames, silhouettes = random_frames(4, n=2, k=3)
    ids = {m: i + 1 for i, m in enumerate(names)}
    sil = np.stack(silhouettes)
    sil[1, 2] = False  # frame 1 has two actors and one padded slot
    batch = batch_mask_stats(torch.from_numpy(np.stack([f.ids for f in frames])), torch.from_numpy(sil),
                             torch.tensor([[1, 2, 3], [1, 2, 0]], dtype=torch.int32))
    got = stats_of(batch, [names, names[:2]])
    assert [len(g) for g in got] == [3, 2]
    assert got[1] == mask_stats(frames[1], dict(zip(names[:2], sil[1, :2])), ids)


def test_shapes_that_do_not_fit_are_refused():
    with pytest.raises(ValueError, match="N frames of K actors"):
        batch_mask_stats(torch.zeros(2, H, W, dtype=torch.int32), torch.zeros(2, 3, H, W, dtype=torch.bool),
                         torch.zeros(2, 2, dtype=torch.int32))
