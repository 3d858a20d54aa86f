"""Ground truth's pixel work on a batch of frames, in torch (on the GPU where the pictures are; CPU tensors in the
tests): entity-id masks -> unoccluded and visible pixel counts, their boxes, border contact.

It gives the same `groundtruth.MaskStats` as the numpy path (`groundtruth.mask_stats`), to the pixel; the records
(`groundtruth.truth_records`: distance, projected truncation, KITTI level) are then built from them as on the
CPU: they need 8 box corners per actor, not pixels, so only these numbers leave the GPU.

Shapes: N frames of H x W; K actors per frame (frames with fewer are padded with empty silhouettes, which give no
record, as an actor out of view does).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from garage_exp.perception.groundtruth import MaskStats


def mask_boxes(masks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Tight boxes (pixel edges x1, y1, x2, y2, as `groundtruth.mask_box`) of (..., H, W) bool masks: (..., 4)
    int64 boxes and (...) bool `empty` (whose boxes are meaningless)."""
    h, w = masks.shape[-2:]
    rows = masks.any(dim=-1).to(torch.uint8)  # (..., H)
    cols = masks.any(dim=-2).to(torch.uint8)  # (..., W)
    # argmax gives the first maximal index: the first row (column) holding a pixel, from either end.
    y1 = rows.argmax(dim=-1)
    y2 = h - rows.flip(-1).argmax(dim=-1)
    x1 = cols.argmax(dim=-1)
    x2 = w - cols.flip(-1).argmax(dim=-1)
    return torch.stack([x1, y1, x2, y2], dim=-1), rows.amax(dim=-1) == 0


def batch_mask_stats(ids: torch.Tensor, silhouettes: torch.Tensor, actor_ids: torch.Tensor,
                     see_through: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """The pixel statistics of K actors in each of N frames, batched.

    ids: (N, H, W) integer entity-id pictures (the Segmentation channel). silhouettes: (N, K, H, W) bool, each
    actor rendered with everything else hidden. actor_ids: (N, K) each actor's id (any value for padding).
    see_through: ids of floor decals that hide nothing (1-D), or None.
    Returns tensors on the inputs' device: unoccluded (N, K), visible (N, K), full_box / visible_box (N, K, 4),
    full_empty / visible_empty (N, K) bool, border (N, K) bool.
    """
    if ids.dim() != 3 or silhouettes.dim() != 4 or silhouettes.shape[0] != ids.shape[0] \
            or silhouettes.shape[2:] != ids.shape[1:] or actor_ids.shape != silhouettes.shape[:2]:
        raise ValueError(f"ids {tuple(ids.shape)}, silhouettes {tuple(silhouettes.shape)} and actor ids "
                         f"{tuple(actor_ids.shape)} do not describe N frames of K actors")
    silhouettes = silhouettes.to(torch.bool)
    shown = ids[:, None] == actor_ids[:, :, None, None]  # (N, K, H, W)
    if see_through is not None and see_through.numel():
        shown = shown | torch.isin(ids, see_through)[:, None]
    visible = shown & silhouettes
    full_box, full_empty = mask_boxes(silhouettes)
    visible_box, visible_empty = mask_boxes(visible)
    border = (silhouettes[..., 0, :].any(-1) | silhouettes[..., -1, :].any(-1)
              | silhouettes[..., :, 0].any(-1) | silhouettes[..., :, -1].any(-1))
    return {"unoccluded": silhouettes.sum(dim=(-2, -1)), "visible": visible.sum(dim=(-2, -1)),
            "full_box": full_box, "full_empty": full_empty, "visible_box": visible_box,
            "visible_empty": visible_empty, "border": border}


def stats_of(batch: dict[str, torch.Tensor], names: Sequence[Sequence[str]]) -> list[list[MaskStats]]:
    """The batch's numbers as `MaskStats`, frame by frame (names[n]: frame n's actors, in silhouette order;
    padding beyond them is dropped). One copy to the CPU for the whole batch."""
    cpu = {k: v.cpu().tolist() for k, v in batch.items()}
    out = []
    for n, frame_names in enumerate(names):
        row = []
        for k, name in enumerate(frame_names):
            if cpu["full_empty"][n][k]:
                row.append(MaskStats(name, 0, 0, None, None, False))
                continue
            visible_box = None if cpu["visible_empty"][n][k] else tuple(cpu["visible_box"][n][k])
            row.append(MaskStats(name, int(cpu["unoccluded"][n][k]), int(cpu["visible"][n][k]),
                                 tuple(cpu["full_box"][n][k]), visible_box, bool(cpu["border"][n][k])))
        out.append(row)
    return out
