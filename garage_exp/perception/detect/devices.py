"""Where a detector's models run: `detector.device` (auto | cpu | cuda) and each entry's pick."""

from __future__ import annotations

from collections.abc import Sequence

from garage_exp.core.errors import GarageError

DEVICES = ("auto", "cpu", "cuda")


def cuda_available() -> bool:
    """Whether torch sees a CUDA GPU (False when torch cannot even be imported)."""
    try:
        import torch

        return bool(torch.cuda.is_available())
    except Exception:  # noqa: BLE001 - a broken CUDA install means: no CUDA
        return False


def check_device(device: object) -> None:
    """`detector.device`: auto | cpu | cuda, and cuda only where torch sees a CUDA GPU."""
    if device not in DEVICES:
        raise GarageError(f"unknown device {device!r} (auto | cpu | cuda)", "detector.device")
    if device == "cuda" and not cuda_available():
        raise GarageError("cuda asked, but torch sees no CUDA GPU (torch.cuda.is_available() is False); "
                          "use auto or cpu", "detector.device")


def pick_device(device: str, cpu_only: bool = False) -> str:
    """The torch device string a model runs on for `device` (auto | cpu | cuda): "cuda:0" for cuda, and for auto
    when torch sees a CUDA GPU; "cpu" for cpu and for a model that runs on the CPU whatever is asked (cpu_only:
    an OpenVINO export, which ultralytics runs on OpenVINO's CPU plugin)."""
    check_device(device)
    if device == "cpu" or cpu_only:
        return "cpu"
    if device == "cuda":
        return "cuda:0"
    return "cuda:0" if cuda_available() else "cpu"


def device_line(device: str, labels: Sequence[str], entries: Sequence) -> str:
    """One log line saying where each model runs and why, e.g.
    "detector device auto -> cpu for yolo11n_int8 (OpenVINO export: CPU only); cuda:0 for yolo11n"."""
    groups: dict[tuple[str, str], list[str]] = {}
    for label, entry in zip(labels, entries):
        note = entry.device_note()
        if not note and entry.device == "cpu" and device == "auto":
            note = "torch sees no CUDA GPU"
        groups.setdefault((entry.device, f" ({note})" if note else ""), []).append(label)
    return f"detector device {device} -> " + "; ".join(
        f"{pick} for {', '.join(names)}{why}" for (pick, why), names in groups.items())
