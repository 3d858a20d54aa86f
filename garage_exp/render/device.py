"""Pick the Vulkan device SAPIEN renders on: a GPU when the machine has one, else Mesa's lavapipe (CPU).

The Vulkan loader reads VK_ICD_FILENAMES once, when SAPIEN creates its instance (the first sapien.Scene()), so
`ensure_device()` must run before that. On a CPU-only machine Mesa's GPU drivers (intel, radeon) are installed
beside lavapipe but find no hardware; pointing the loader at lavapipe alone skips probing them.
"""

from __future__ import annotations

import glob
import logging
import os

from garage_exp.core.errors import GarageError

ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")
ICD_VARS = ("VK_ICD_FILENAMES", "VK_DRIVER_FILES")
log = logging.getLogger(__name__)
INSTALL_HINT = ("run `make setup` or install libvulkan1 and mesa-vulkan-drivers >= 25 "
                "(Debian 12: from bookworm-backports) or a GPU driver")

_checked: str | None = None  # the device summary once a device was found
# SAPIEN drops its Vulkan context (and every compiled pipeline) when the last scene, material and shape die,
# so a job that replaces its scene would pay the 3-6 s shader compilation again. Holding the engine keeps it.
_engine: object | None = None


def gpu_present() -> bool:
    """True when a GPU device node exists: NVIDIA's (with its ICD) or a DRM render node (Mesa drivers)."""
    if glob.glob("/dev/nvidia[0-9]*") and any(glob.glob(f"{d}/nvidia*.json") for d in ICD_DIRS):
        return True
    return bool(glob.glob("/dev/dri/renderD*"))


def lavapipe_icd() -> str | None:
    for d in ICD_DIRS:
        found = sorted(glob.glob(f"{d}/lvp_icd*.json"))
        if found:
            return found[0]
    return None


def choose_icd() -> str | None:
    """Set VK_ICD_FILENAMES to lavapipe when no GPU is present and the user set no ICD; returns what it set."""
    if any(os.environ.get(v) for v in ICD_VARS) or gpu_present():
        return None
    icd = lavapipe_icd()
    if icd is not None:
        os.environ["VK_ICD_FILENAMES"] = icd
    return icd


def ensure_device() -> str:
    """Make sure SAPIEN has a Vulkan device to render on; returns SAPIEN's one-line device summary.

    Raises GarageError (one line, naming what to install) when there is none. Idempotent and cheap after the
    first call.
    """
    global _checked, _engine
    if _checked is not None:
        return _checked
    choose_icd()
    try:
        import sapien.render

        devices = supported_devices(sapien.render.get_device_summary())
        if devices:
            _engine = sapien.render.SapienRenderer()
    except Exception as exc:  # noqa: BLE001 - any failure here means no usable device
        raise GarageError(f"SAPIEN found no Vulkan device ({_first_line(exc)}): {INSTALL_HINT}", "renderer") from exc
    if not devices:
        icds = os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES") or "default ICDs"
        raise GarageError(f"SAPIEN found no Vulkan device it can render on (ICD: {icds}): {INSTALL_HINT}",
                          "renderer")
    _checked = devices[0]
    log.info("SAPIEN renders on %s", _checked)
    return _checked


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
