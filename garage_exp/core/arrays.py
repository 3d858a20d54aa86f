"""The few array operations that numpy and torch spell differently, so that ground truth and the camera model are
written once and run on numpy arrays (the CPU path, byte for byte as before) or torch tensors (the GPU path, where
the pictures are).

Everything else the callers do is spelled the same in both (operators, `.any(axis=)`, `.sum(axis=)`,
`.clip(min, max)`, `.tolist()`); what is here is only what is not. torch is imported only when a tensor is
passed, so the CPU path runs without it.
"""

from __future__ import annotations

import numpy as np

from garage_exp.core.state import STATE


def is_torch(x) -> bool:
    """Whether `x` is a torch tensor (checked by type, without importing torch)."""
    return type(x).__module__.startswith("torch")


def xp(x):
    """The array's own namespace (numpy or torch) for what both have under one name: where, sqrt, stack."""
    if is_torch(x):
        import torch

        return torch
    return np


# Constant tables copied to a device, by (key, device): once per process, not once per batch.
_ON_DEVICE: dict[tuple, object] = STATE.cache("perception.arrays.tables", "process")


def table(values: np.ndarray, like, key: tuple | None = None):
    """A constant numpy table as an array of `like`'s kind: itself for numpy, a tensor on `like`'s device for
    torch (kept under `key` when one is given)."""
    if not is_torch(like):
        return values
    import torch

    where = (key, str(like.device))
    if key is not None and where in _ON_DEVICE:
        return _ON_DEVICE[where]
    out = torch.from_numpy(np.ascontiguousarray(values)).to(like.device)
    if key is not None:
        _ON_DEVICE[where] = out
    return out


def take(values, index):
    """values[index] with an integer index array of any width (torch reads a uint8 index as a mask)."""
    if is_torch(index):
        return values[index.long()]
    return values[index]


def column(values, dtype, like):
    """One value per frame as an (N, 1, 1, 1) array of `like`'s kind, for per-frame factors."""
    if is_torch(like):
        import torch

        return torch.tensor(values, dtype=getattr(torch, np.dtype(dtype).name), device=like.device).view(-1, 1, 1, 1)
    return np.asarray(values, dtype=dtype).reshape(-1, 1, 1, 1)


def frame_means(x) -> list[float]:
    """Each frame's mean over everything but the first axis. numpy takes the frames one by one (the sum's order
    of a lone frame, hence its exact mean); torch all at once, with one copy to the CPU."""
    if is_torch(x):
        return x.mean(dim=tuple(range(1, x.dim()))).tolist()
    return [float(frame.mean()) for frame in x]


def flip(x, axis: int):
    return x.flip(axis) if is_torch(x) else np.flip(x, axis)


def isin(x, values) -> object:
    """Where x holds one of `values` (a sequence of ints)."""
    if is_torch(x):
        import torch

        return torch.isin(x, torch.as_tensor(list(values), dtype=x.dtype, device=x.device))
    return np.isin(x, list(values))


def as_int(x):
    """Integer array of x's values (truncated), for table lookups."""
    if is_torch(x):
        import torch

        return x.to(torch.int64)
    return x.astype(np.int32)


def as_uint8(x):
    """x rounded half to even, as 8-bit values."""
    if is_torch(x):
        import torch

        return torch.round(x).to(torch.uint8)
    return np.rint(x).astype(np.uint8)


def cast(x, dtype):
    """x as numpy `dtype` (np.float32, np.float64), or the torch dtype of that name."""
    if is_torch(x):
        import torch

        return x.to(getattr(torch, np.dtype(dtype).name))
    return x.astype(dtype)


# -- random numbers. The source decides the stream: a numpy Generator draws numpy's numbers whatever the arrays'
# kind (a torch batch then sees what a numpy batch would: the CPU path's stream, and the agreement tests); a torch
# Generator (or None: torch's default) draws on the tensors' device.

def _drawn(values: np.ndarray, like):
    if not is_torch(like):
        return values
    import torch

    return torch.from_numpy(values).to(like.device)


def standard_normal(rng, like):
    """float32 standard normals of `like`'s shape, kind and device."""
    if isinstance(rng, np.random.Generator):
        return _drawn(rng.standard_normal(tuple(like.shape), dtype=np.float32), like)
    import torch

    return torch.randn(tuple(like.shape), generator=rng, dtype=torch.float32, device=like.device)


def normal(rng, sd: float, like):
    """float32 normals of standard deviation `sd`, of `like`'s shape, kind and device."""
    if isinstance(rng, np.random.Generator):
        return _drawn(rng.normal(0.0, sd, size=tuple(like.shape)).astype(np.float32), like)
    return sd * standard_normal(rng, like)


def poisson(rng, expected):
    """Poisson counts of the float64 rates `expected`, as float64."""
    if isinstance(rng, np.random.Generator):
        rates = expected.cpu().numpy() if is_torch(expected) else expected
        return _drawn(rng.poisson(rates).astype(np.float64), expected)
    import torch

    return torch.poisson(expected, generator=rng)


# -- a Gaussian blur as OpenCV's (cv2.GaussianBlur, BORDER_REFLECT), per frame of (N, H, W, C) float32

def gaussian_blur(x, sigma: float):
    if not is_torch(x):
        import cv2

        out = np.empty_like(x)
        for k, frame in enumerate(x):
            out[k] = cv2.GaussianBlur(frame, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
        return out
    import torch.nn.functional as F

    k = gaussian_kernel(sigma).to(x.device)
    pad = (len(k) - 1) // 2
    planes = x.permute(0, 3, 1, 2).reshape(-1, 1, *x.shape[1:3])  # (N*C, 1, H, W)
    planes = F.conv2d(_reflect(planes, pad, 3), k.view(1, 1, 1, -1))
    planes = F.conv2d(_reflect(planes, pad, 2), k.view(1, 1, -1, 1))
    return planes.reshape(x.shape[0], x.shape[3], *x.shape[1:3]).permute(0, 2, 3, 1)


def gaussian_kernel(sigma: float):
    """OpenCV's Gaussian kernel for a float32 picture (cv2.getGaussianKernel, ksize = round(8 sigma + 1) | 1)."""
    import torch

    size = int(round(sigma * 8 + 1)) | 1
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    k = torch.exp(-x * x / (2 * sigma * sigma))
    return (k / k.sum()).to(torch.float32)


def _reflect(x, pad: int, dim: int):
    """Pad `dim` by mirroring with the edge pixel repeated (OpenCV's BORDER_REFLECT: fedcba|abcdef|fedcba)."""
    import math

    import torch

    n = x.shape[dim]
    if pad > n:  # a kernel wider than the picture: mirror repeatedly
        reps = math.ceil(pad / n) + 1
        parts = [x if i % 2 == 0 else x.flip(dim) for i in range(2 * reps + 1)]
        return torch.cat(parts, dim).narrow(dim, reps * n - pad, n + 2 * pad)
    return torch.cat([x.narrow(dim, 0, pad).flip(dim), x, x.narrow(dim, n - pad, pad).flip(dim)], dim)
