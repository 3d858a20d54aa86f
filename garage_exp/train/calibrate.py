"""BatchNorm calibration of a base before fine-tuning (`bn_calibrate=N`, issue 39 item 4).

The COCO detector the loop starts from (`../shared/models/yolo11n_fp32_from_int8.pt`, SOURCES.txt there) was rebuilt
from an INT8 export with its BatchNorms folded into the convolutions and set to identity (mean 0, variance 1). In
eval mode that is exact; in train mode each BatchNorm normalises by the batch's own statistics, which the folded
weights were never scaled for, and the detector is wrecked in the first step. Calibrating sets each BatchNorm's
running mean m and variance v to the statistics of its input over images of what the fine-tuning will see, and
rescales its weight and bias so that eval outputs do not change:

    w' = w sqrt(v + eps) / sqrt(rv + eps),   b' = b + w (m - rm) / sqrt(rv + eps),   rm' = m,   rv' = v

(for the identity BatchNorms, w' = sqrt(v + eps) and b' = b + m, as SOURCES.txt says). Batch statistics of the
training images then agree with the running ones, so train mode computes about what eval mode does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def letterboxed(path: Path, imgsz: int) -> np.ndarray:
    """An image as ultralytics feeds it: letterboxed to imgsz x imgsz (grey 114 padding), RGB, CHW, 0-1."""
    from PIL import Image

    with Image.open(path) as im:
        rgb = im.convert("RGB")
        scale = min(imgsz / rgb.width, imgsz / rgb.height)
        size = (max(1, round(rgb.width * scale)), max(1, round(rgb.height * scale)))
        canvas = Image.new("RGB", (imgsz, imgsz), (114, 114, 114))
        canvas.paste(rgb.resize(size, Image.BILINEAR), ((imgsz - size[0]) // 2, (imgsz - size[1]) // 2))
    return np.asarray(canvas, dtype=np.float32).transpose(2, 0, 1) / 255.0


def batchnorm_stats(model, images: list[Path], imgsz: int, batch: int = 8) -> dict:
    """Each BatchNorm2d's input mean and (population) variance per channel over the images (eval mode)."""
    import torch

    sums: dict = {}

    def hook(module, inputs, _output):
        x = inputs[0].detach().double()
        s = sums.setdefault(module, [0.0, 0.0, 0])
        s[0] = s[0] + x.sum(dim=(0, 2, 3))
        s[1] = s[1] + (x * x).sum(dim=(0, 2, 3))
        s[2] += x.numel() // x.shape[1]

    bns = [m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    handles = [m.register_forward_hook(hook) for m in bns]
    model.eval()
    try:
        with torch.no_grad():
            for k in range(0, len(images), batch):
                x = torch.from_numpy(np.stack([letterboxed(p, imgsz) for p in images[k:k + batch]]))
                model(x)
    finally:
        for h in handles:
            h.remove()
    out = {}
    for m, (s, ss, n) in sums.items():
        mean = s / n
        out[m] = (mean, (ss / n - mean * mean).clamp(min=0.0))
    return out


def calibrate_model(model, images: list[Path], imgsz: int) -> int:
    """Calibrate every BatchNorm2d of a torch model in place (output-preserving in eval mode); returns how many."""
    import torch

    stats = batchnorm_stats(model, images, imgsz)
    with torch.no_grad():
        for bn, (m, v) in stats.items():
            restat(bn, m, v)
    return len(stats)


def restat(bn, mean, var) -> None:
    """A BatchNorm written in the running statistics (mean, var) without changing what it computes in eval mode
    (the rule above), in place; the caller holds torch.no_grad(). Also how train/wise.py aligns two models'."""
    import torch

    m, v = mean.double(), var.double()
    rm, rv = bn.running_mean.double(), bn.running_var.double()
    w, b = bn.weight.double(), bn.bias.double()
    old = torch.sqrt(rv + bn.eps)
    bn.weight.copy_((w * torch.sqrt(v + bn.eps) / old).to(bn.weight.dtype))
    bn.bias.copy_((b + w * (m - rm) / old).to(bn.bias.dtype))
    bn.running_mean.copy_(m.to(bn.running_mean.dtype))
    bn.running_var.copy_(v.to(bn.running_var.dtype))


def calibrate(base: Path, images: list[Path], imgsz: int, out: Path) -> Path:
    """A copy of the ultralytics checkpoint `base` with its BatchNorms calibrated on `images`, in float32, at `out`."""
    import torch
    from ultralytics.nn.tasks import torch_safe_load

    # An ultralytics checkpoint pickles its model's classes: loaded as ultralytics loads every `.pt` the project
    # runs (its own loader), not with a bare torch.load (tests/test_reliability_inputs.py's static guard).
    ckpt, _ = torch_safe_load(str(base))
    for key in ("model", "ema"):
        if ckpt.get(key) is not None:
            ckpt[key] = ckpt[key].float()
            calibrate_model(ckpt[key], images, imgsz)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(ckpt, str(out))
    return out
