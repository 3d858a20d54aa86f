"""Which Vulkan ICD files this machine has, and whether `renderer.device` (auto | cpu | cuda) can be had here.

File globs only, no SAPIEN: the preflight checks a config with it (render.open.check_renderer), and device.py points
the Vulkan loader with it.
"""

from __future__ import annotations

import glob

from garage_exp.core.errors import GarageError

ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")
# Where container runtimes mount NVIDIA's driver files when the image has no ICD of its own.
NVIDIA_ICD_DIRS = (*ICD_DIRS, "/usr/local/nvidia/share/vulkan/icd.d")
DEVICES = ("auto", "cpu", "cuda")
ICD_VARS = ("VK_ICD_FILENAMES", "VK_DRIVER_FILES")
INSTALL_HINT = ("run `make setup` or install libvulkan1 and mesa-vulkan-drivers >= 25 "
                "(Debian 12: from bookworm-backports) or a GPU driver")


def gpu_present() -> bool:
    """True when a GPU device node exists: NVIDIA's (with its ICD) or a DRM render node (Mesa drivers)."""
    if glob.glob("/dev/nvidia[0-9]*") and any(glob.glob(f"{d}/nvidia*.json") for d in ICD_DIRS):
        return True
    return bool(glob.glob("/dev/dri/renderD*"))


def nvidia_icd() -> str | None:
    """NVIDIA's Vulkan ICD file when the machine has an NVIDIA device node and the driver's ICD, else None."""
    if not glob.glob("/dev/nvidia[0-9]*"):
        return None
    for d in NVIDIA_ICD_DIRS:
        found = sorted(glob.glob(f"{d}/nvidia*.json"))
        if found:
            return found[0]
    return None


def check_device(device: object, where: str) -> None:
    if device not in DEVICES:
        raise GarageError(f"unknown device {device!r} (auto | cpu | cuda)", where)


def lavapipe_icd() -> str | None:
    for d in ICD_DIRS:
        found = sorted(glob.glob(f"{d}/lvp_icd*.json"))
        if found:
            return found[0]
    return None


def check_available(device: str) -> None:
    """GarageError (one line) when `device` is not auto|cpu|cuda, or asks for an ICD this machine lacks.
    Cheap (file globs, no Vulkan): the preflight runs it."""
    check_device(device, "renderer.device")
    if device == "cpu" and lavapipe_icd() is None:
        raise GarageError(f"cpu needs Mesa's lavapipe, which is not installed: {INSTALL_HINT}",
                          "renderer.device")
    if device == "cuda" and nvidia_icd() is None:
        why = ("no NVIDIA device (/dev/nvidia0)" if not glob.glob("/dev/nvidia[0-9]*")
               else "no NVIDIA Vulkan ICD (nvidia_icd.json)")
        raise GarageError(f"cuda needs an NVIDIA GPU, and this machine has {why}; use auto or cpu, or run "
                          "scripts/setup_vulkan.sh on a machine with an NVIDIA driver", "renderer.device")
