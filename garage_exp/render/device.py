"""Pick the Vulkan device SAPIEN renders on (`renderer.device`): auto, cpu or cuda.

- auto: a GPU when the machine has one, else Mesa's lavapipe (CPU);
- cpu: lavapipe, even on a machine with a GPU;
- cuda: NVIDIA's Vulkan driver (its ICD, nvidia_icd.json); a GarageError when the machine has none.

The Vulkan loader reads VK_ICD_FILENAMES once, when SAPIEN creates its instance (the first sapien.Scene()), so
`ensure_device()` must run before that, and a process renders on one device for its whole life. On a CPU-only
machine Mesa's GPU drivers (intel, radeon) are installed beside lavapipe but find no hardware; pointing the
loader at lavapipe alone skips probing them.
"""

from __future__ import annotations

import logging
import os

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE
from garage_exp.render.icd import (ICD_DIRS, ICD_VARS, INSTALL_HINT, check_available, gpu_present, lavapipe_icd,
                                   nvidia_icd)

log = logging.getLogger(__name__)

# The process's device once found: "checked" (SAPIEN's device summary), "kind" (what it is: "cpu" (lavapipe),
# "cuda" (NVIDIA) or "gpu" (another GPU)) and "engine": SAPIEN drops its Vulkan context (and every compiled
# pipeline) when the last scene, material and shape die, so a job that replaces its scene would pay the 3-6 s
# shader compilation again. Holding the engine keeps it.
_DEVICE: dict[str, object] = STATE.cache("render.device", "process")


def choose_icd(device: str = "auto") -> str | None:
    """Point the Vulkan loader at the ICD `device` asks for; returns the ICD file it set, None when it set none.

    auto: lavapipe when no GPU is present and the user set no ICD, else the loader's own choice (unchanged).
    cpu: lavapipe; cuda: NVIDIA's ICD. Each replaces an ICD the user set, and is a GarageError when absent.
    """
    check_available(device)
    if device == "auto":
        if any(os.environ.get(v) for v in ICD_VARS):
            return None
        nvidia = nvidia_icd()
        if nvidia is not None and os.path.dirname(nvidia) not in ICD_DIRS:
            icd = nvidia  # mounted with the driver where the loader does not look (/usr/local/nvidia)
        elif gpu_present():
            return None
        else:
            icd = lavapipe_icd()
    else:
        icd = lavapipe_icd() if device == "cpu" else nvidia_icd()
    if icd is not None:
        # VK_DRIVER_FILES wins over VK_ICD_FILENAMES in newer loaders: one variable, so the choice holds.
        STATE.popenv("VK_DRIVER_FILES", "process")
        STATE.setenv("VK_ICD_FILENAMES", icd, "process")
    return icd


def device_kind(name: str) -> str:
    """"cpu" for Mesa's lavapipe (llvmpipe), "cuda" for an NVIDIA GPU, else "gpu"."""
    lowered = name.lower()
    if "llvmpipe" in lowered or "lavapipe" in lowered:
        return "cpu"
    return "cuda" if "nvidia" in lowered else "gpu"


def ensure_device(device: str = "auto") -> str:
    """Make sure SAPIEN has a Vulkan device to render on (`device`: auto | cpu | cuda); returns SAPIEN's one-line
    device summary.

    Raises GarageError (one line, naming what to install) when there is none, or when this process already
    renders on another device than `device` asks for (the loader reads its ICD once). Idempotent and cheap after
    the first call.
    """
    checked = _DEVICE.get("checked")
    if checked is not None:
        check_available(device)
        if device != "auto" and device != _DEVICE["kind"]:
            raise GarageError(f"{device} asked, but this process already renders on {checked} "
                              "(a process keeps its first Vulkan device); run it in a new process",
                              "renderer.device")
        return checked
    choose_icd(device)
    try:
        import sapien.render

        devices = supported_devices(sapien.render.get_device_summary())
        if devices:
            _DEVICE["engine"] = sapien.render.SapienRenderer()
    except Exception as exc:  # noqa: BLE001 - any failure here means no usable device
        raise GarageError(f"SAPIEN found no Vulkan device ({_first_line(exc)}): {INSTALL_HINT}", "renderer") from exc
    if not devices:
        icds = os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES") or "default ICDs"
        raise GarageError(f"SAPIEN found no Vulkan device it can render on (ICD: {icds}): {INSTALL_HINT}",
                          "renderer")
    if device != "auto" and device_kind(devices[0]) != device:
        raise GarageError(f"{device} asked, but SAPIEN found only {devices[0]}", "renderer.device")
    _DEVICE.update(checked=devices[0], kind=device_kind(devices[0]))
    log.info("renderer device %s -> %s (Vulkan)", device, devices[0].split(": ", 1)[-1])
    return devices[0]


def supported_devices(summary: str) -> list[str]:
    """Names of the devices SAPIEN's summary marks "Supported: 1" (each block starts with an unindented line)."""
    out, name = [], None
    for line in summary.splitlines():
        if line and not line[0].isspace():
            name = line.strip()
        elif line.strip().replace(" ", "") == "Supported:1" and name:
            out.append(name)
    return out


def device_problem() -> str | None:
    """Why rendering cannot work here, or None when it can (for skipping render tests with a reason)."""
    try:
        ensure_device()
    except GarageError as exc:
        return str(exc)
    return None


def _first_line(obj: object) -> str:
    text = str(obj).strip()
    return text.splitlines()[0] if text else type(obj).__name__
