"""The fisheye remaps (render/fisheye.py) on a batch of pictures in torch, where the pictures are (the GPU path):
colour with `grid_sample` (bilinear, the maps' -1 outside the lens giving black as cv2.remap's constant border
does), ids by the nearest atlas pixel's flat index (exact: the same indices as `fisheye.lookup`).

Colour agrees with cv2.remap within one 8-bit level (OpenCV quantises each sample's position to 1/32 pixel,
grid_sample does not; tests/test_fisheye_torch.py).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F


def sampling_grid(map_x: np.ndarray, map_y: np.ndarray, width: int, height: int,
                  device: str | torch.device = "cpu") -> torch.Tensor:
    """cv2.remap's maps (pixel centres at integers) as grid_sample's (1, h, w, 2) grid over a width x height
    picture (align_corners=True: -1 and 1 are the centres of the first and last pixels)."""
    gx = torch.from_numpy(np.asarray(map_x, np.float32)) * (2.0 / max(width - 1, 1)) - 1.0
    gy = torch.from_numpy(np.asarray(map_y, np.float32)) * (2.0 / max(height - 1, 1)) - 1.0
    return torch.stack([gx, gy], dim=-1)[None].to(device)


def remap_bilinear(pictures: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """(N, H, W, C) pictures (uint8 or float) sampled at `grid` (`sampling_grid`): (N, h, w, C) of the same dtype
    (uint8 rounded to nearest)."""
    x = pictures.permute(0, 3, 1, 2).float()
    out = F.grid_sample(x, grid.expand(len(x), -1, -1, -1), mode="bilinear", padding_mode="zeros",
                        align_corners=True).permute(0, 2, 3, 1)
    if pictures.dtype == torch.uint8:
        return out.round().clamp(0, 255).to(torch.uint8)
    return out.to(pictures.dtype)


def lookup(pictures: torch.Tensor, flat: np.ndarray | torch.Tensor, fill=0) -> torch.Tensor:
    """Nearest-neighbour remap of (N, H, W, ...) pictures at flat pixel indices (h x w, -1: `fill`), as
    `fisheye.lookup` does one picture."""
    flat = torch.as_tensor(flat, device=pictures.device)
    n = pictures.shape[0]
    src = pictures.reshape(n, -1, *pictures.shape[3:])
    out = src[:, flat.clamp(min=0).reshape(-1)].reshape(n, *flat.shape, *pictures.shape[3:])
    out[:, flat < 0] = fill
    return out
