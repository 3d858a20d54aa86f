"""Weight-space ensembling of a fine-tuned detector with its base (WiSE-FT: Wortsman et al., "Robust fine-tuning of
zero-shot models", CVPR 2022): theta = alpha * theta_tuned + (1 - alpha) * theta_base, every weight interpolated.
Fine-tuned from the base with a small learning rate, the two sit in one basin, and the mix keeps most of what the
fine-tuning learned while giving back what it forgot of the base's world (the paper's "alpha = 0.5" mixes lose
little in distribution and regain the base's robustness). The loop uses it for the detectors it delivers
(`wise`, docs/loop.md "Not forgetting").

BatchNorms need one step first. The base and the tuned model normalise by different running statistics (the loop's
base has identity BatchNorms folded into its convolutions; each fine-tuning calibrates and then moves them), so
their weight and bias do not mean the same thing and averaging them would mix two scales. The base's BatchNorm is
first written in the tuned one's statistics without changing what it computes in eval mode (calibrate.py's rule:
the per-channel affine a = w / sqrt(v + eps), c = b - a m stays, the statistics become the tuned ones), then weight
and bias are interpolated and the tuned statistics kept. With alpha = 0 the result computes what the base does;
with alpha = 1 it is the tuned model.
"""

from __future__ import annotations

from pathlib import Path


def mix_models(base, tuned, alpha: float):
    """`tuned` (a torch module, float) with its weights interpolated toward `base`'s (the same architecture), in
    place; returns it."""
    import torch

    from garage_exp.train.calibrate import restat

    if [n for n, _ in base.named_modules()] != [n for n, _ in tuned.named_modules()]:
        raise ValueError("the base and the tuned model differ in architecture")
    own = dict(base.named_modules())
    stats = set()  # running statistics: the tuned model's, as they are
    with torch.no_grad():
        for name, bn in tuned.named_modules():
            if not isinstance(bn, torch.nn.BatchNorm2d):
                continue
            restat(own[name], bn.running_mean, bn.running_var)  # the base's, in the tuned model's statistics
            stats.update(f"{name}.{key}" for key in ("running_mean", "running_var", "num_batches_tracked"))
        theirs = base.state_dict()
        for key, value in tuned.state_dict().items():
            if key in stats or not value.is_floating_point():
                continue
            value.copy_(alpha * value + (1.0 - alpha) * theirs[key].to(value.dtype))
    return tuned


def interpolate(base: Path, tuned: Path, alpha: float, out: Path) -> Path:
    """The ultralytics checkpoint `tuned` with its model's weights interpolated toward `base`'s, in float32, at
    `out` (the checkpoint's other entries, its training arguments among them, as `tuned` has them)."""
    import torch
    from ultralytics.nn.tasks import torch_safe_load

    from garage_exp.core.errors import check_range

    check_range(alpha, 0.0, 1.0, "wise", f"{alpha} (the fine-tuned weights' share: 0 the base, 1 as trained)")
    # Loaded as ultralytics loads every `.pt` the project runs (its own loader; calibrate.py says why).
    ours, _ = torch_safe_load(str(tuned))
    theirs, _ = torch_safe_load(str(base))
    model = (ours.get("ema") or ours["model"]).float()
    mix_models((theirs.get("ema") or theirs["model"]).float(), model, alpha)
    ours.update(model=model, ema=None, wise={"alpha": alpha, "base": str(base), "tuned": str(tuned)})
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(ours, str(out))
    return out


def validate(weights: Path, data: Path, imgsz: int) -> dict:
    """The mix's mAP50, recall and precision on a fine-tuning's validation split (`data`: its data.yaml), as the
    fine-tuning's own validation measured the tuned model (ultralytics' val, the same image size)."""
    from ultralytics import YOLO

    metrics = YOLO(str(weights)).val(data=str(data), imgsz=imgsz, batch=16, plots=False,
                                     verbose=False, save_json=False, project=str(weights.parent / "val"),
                                     name=weights.stem, exist_ok=True).results_dict
    return {"map50": float(metrics["metrics/mAP50(B)"]), "recall": float(metrics["metrics/recall(B)"]),
            "precision": float(metrics["metrics/precision(B)"])}
