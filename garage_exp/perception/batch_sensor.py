"""The camera model (`perception.sensor.SensorModel`) on a batch of frames in torch, where the pictures are (the
GPU path; CPU tensors in the tests).

The same chain as `SensorModel.apply`, frame by frame within the batch (each frame's own auto-exposure):
sRGB -> linear (the same 256-entry table) -> lens blur (OpenCV's Gaussian kernel and BORDER_REFLECT edges) ->
vignetting -> AE -> noise -> tone curve and sRGB (the same output table for the "camera" kind).

Noise: torch draws its own random numbers (`generator`), so a torch frame is not the numpy frame of the same
seed; `normals` lets a caller (the agreement test) feed the numpy stream's normals to the "camera" kind, which
then agrees with numpy to one 8-bit level (float32 sums in another order). The CPU path keeps the numpy model:
its tables stay byte-identical.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from garage_exp.core.state import STATE
from garage_exp.perception import sensor as numpy_sensor
from garage_exp.perception.sensor import SensorModel


@STATE.memo("process", maxsize=16)
def _table(name: str, device: str, *key) -> torch.Tensor:
    """The numpy model's lookup tables as tensors, once per device."""
    if name == "linear":
        return torch.from_numpy(numpy_sensor._LINEAR_LUT).to(device)
    if name == "output":
        return torch.from_numpy(np.ascontiguousarray(numpy_sensor._output_table(*key))).to(device)
    return torch.from_numpy(numpy_sensor._falloff(*key)).to(device)  # "falloff": (shape, strength)


def gaussian_kernel(sigma: float) -> torch.Tensor:
    """OpenCV's Gaussian kernel for a float32 picture (cv2.getGaussianKernel with ksize = round(8 sigma + 1) | 1)."""
    size = int(round(sigma * 8 + 1)) | 1
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    k = torch.exp(-x * x / (2 * sigma * sigma))
    return (k / k.sum()).to(torch.float32)


def _reflect(x: torch.Tensor, pad: int, dim: int) -> torch.Tensor:
    """Pad `dim` by mirroring with the edge pixel repeated (OpenCV's BORDER_REFLECT: fedcba|abcdef|fedcba)."""
    n = x.shape[dim]
    if pad > n:  # a kernel wider than the picture: mirror repeatedly
        reps = math.ceil(pad / n) + 1
        parts = [x if i % 2 == 0 else x.flip(dim) for i in range(2 * reps + 1)]
        tiled = torch.cat(parts, dim)
        return tiled.narrow(dim, reps * n - pad, n + 2 * pad)
    return torch.cat([x.narrow(dim, 0, pad).flip(dim), x, x.narrow(dim, n - pad, pad).flip(dim)], dim)


def blur(radiance: torch.Tensor, sigma: float) -> torch.Tensor:
    """(N, H, W, 3) float32 blurred as cv2.GaussianBlur(sigma, BORDER_REFLECT), separably."""
    k = gaussian_kernel(sigma).to(radiance.device)
    pad = (len(k) - 1) // 2
    x = radiance.permute(0, 3, 1, 2).reshape(-1, 1, *radiance.shape[1:3])  # (N*3, 1, H, W)
    x = F.conv2d(_reflect(x, pad, 3), k.view(1, 1, 1, -1))
    x = F.conv2d(_reflect(x, pad, 2), k.view(1, 1, -1, 1))
    return x.reshape(radiance.shape[0], 3, *radiance.shape[1:3]).permute(0, 2, 3, 1)


def srgb_encode(v: torch.Tensor) -> torch.Tensor:
    v = v.clamp(0.0, 1.0)
    return torch.where(v <= 0.0031308, v * 12.92, 1.055 * v.pow(1.0 / 2.4) - 0.055)


def apply_batch(model: SensorModel, rgb: torch.Tensor, generator: torch.Generator | None = None,
                normals: torch.Tensor | None = None) -> torch.Tensor:
    """The frames (N, H, W, 3) uint8 as `model` delivers them: uint8 (float32 when `quantize` is off), on the
    frames' device. generator: the noise's random stream; normals: (N, H, W, 3) standard normals to use instead
    (the "camera" kind only)."""
    if rgb.dim() != 4 or rgb.shape[-1] != 3 or rgb.dtype != torch.uint8:
        raise ValueError(f"expected (N, H, W, 3) uint8 frames, got {rgb.dtype} {tuple(rgb.shape)}")
    if model.kind == "ideal":
        return rgb
    device = str(rgb.device)
    radiance = _table("linear", device)[rgb.long()]
    if model.blur_sigma > 0:
        radiance = blur(radiance, model.blur_sigma)
    if model.vignetting > 0:
        radiance = radiance * _table("falloff", device, tuple(rgb.shape[1:3]), model.vignetting)[..., None]
    means = radiance.mean(dim=(1, 2, 3)).tolist()  # one sync for the batch: the AE decides per frame
    chosen = [model.exposure_and_gain(m) for m in means]
    scale = torch.tensor([e * model.full_well for e, _ in chosen], dtype=torch.float32, device=rgb.device)
    gain = torch.tensor([g / model.full_well for _, g in chosen], dtype=torch.float32, device=rgb.device)
    view = (-1, 1, 1, 1)
    if model.kind == "camera":
        expected = radiance * scale.view(view)
        if normals is None:
            normals = torch.randn(expected.shape, generator=generator, dtype=torch.float32, device=rgb.device)
        sd = torch.sqrt(expected + np.float32(model.read_noise ** 2))
        electrons = expected + sd * normals
        signal = torch.clamp(electrons, max=float(np.float32(model.full_well))) * gain.view(view)
        steps = numpy_sensor._OUT_STEPS
        index = torch.clamp(signal * np.float32(steps / numpy_sensor._OUT_RANGE), 0, steps - 1).to(torch.int64)
        return _table("output", device, model.tone, model.quantize)[index]
    expected = radiance.double() * scale.double().view(view)
    electrons = torch.clamp(torch.poisson(expected, generator=generator), max=model.full_well).float()
    if model.read_noise > 0:
        electrons = electrons + model.read_noise * torch.randn(electrons.shape, generator=generator,
                                                               device=rgb.device)
    signal = electrons * gain.view(view)
    if model.tone == "filmic":
        signal = signal.clamp(min=0.0)
        signal = (signal * (2.51 * signal + 0.03)) / (signal * (2.43 * signal + 0.59) + 0.14)
    out = srgb_encode(signal)
    return out if not model.quantize else torch.round(out * 255.0).to(torch.uint8)
