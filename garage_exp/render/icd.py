"""Which Vulkan driver (ICD) the loader gets, from files alone (no SAPIEN, no Vulkan): `renderer.device`'s
auto | cpu | cuda checked and applied. The preflight checks a config with it; render.device uses it before SAPIEN
creates its instance."""

from __future__ import annotations

import glob
import os

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
        os.environ.pop("VK_DRIVER_FILES", None)
        os.environ["VK_ICD_FILENAMES"] = icd
    return icd


def device_kind(name: str) -> str:
    """"cpu" for Mesa's lavapipe (llvmpipe), "cuda" for an NVIDIA GPU, else "gpu"."""
    lowered = name.lower()
    if "llvmpipe" in lowered or "lavapipe" in lowered:
        return "cpu"
    return "cuda" if "nvidia" in lowered else "gpu"
