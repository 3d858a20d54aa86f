#!/usr/bin/env bash
# Bring the machine to a Vulkan device SAPIEN 3 accepts (docs/gpu.md).
# - With an NVIDIA GPU (/dev/nvidia0 and the driver's Vulkan ICD, nvidia_icd.json): the Vulkan loader
#   (libvulkan1) and the GL vendor-neutral dispatch libraries NVIDIA's Vulkan driver loads (libglvnd0, libglx0,
#   libegl1: without libegl1 SAPIEN found no device on an H100 machine), and the ICD where the loader looks.
#   Container runtimes mount the driver's files, the ICD included, but images often lack the rest; some mount
#   the ICD under /usr/local/nvidia/share/vulkan/icd.d, which the loader does not read, so it is linked into
#   /etc/vulkan/icd.d. No Mesa is needed.
# - Otherwise (CPU only, Debian 12): Mesa >= 25 lavapipe from bookworm-backports (Mesa 22.3 lacks
#   descriptorBindingPartiallyBound).
# Idempotent: does nothing when what the machine needs is already installed.
set -euo pipefail

STANDARD_ICD_DIRS="/usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/share/vulkan/icd.d"

has_lib() {
  ldconfig -p 2>/dev/null | grep -q "$1" || [ -e "/usr/lib/x86_64-linux-gnu/$1" ]
}

# What NVIDIA's Vulkan driver needs besides itself (docs/gpu.md).
have_nvidia_runtime() {
  has_lib libvulkan.so.1 && has_lib libGLdispatch.so.0 && has_lib libGLX.so.0 && has_lib libEGL.so.1
}

nvidia_icd() {
  local d f
  for d in $STANDARD_ICD_DIRS /usr/local/nvidia/share/vulkan/icd.d; do
    for f in "$d"/nvidia*.json; do
      [ -f "$f" ] && { echo "$f"; return 0; }
    done
  done
  return 1
}

if ls /dev/nvidia[0-9]* >/dev/null 2>&1 && icd=$(nvidia_icd); then
  case " $STANDARD_ICD_DIRS " in
    *" $(dirname "$icd") "*) ;;
    *) if [ "$(id -u)" = 0 ]; then
         mkdir -p /etc/vulkan/icd.d && ln -sf "$icd" /etc/vulkan/icd.d/nvidia_icd.json
       else
         echo "garage_exp: NVIDIA's Vulkan ICD is at $icd, where the Vulkan loader does not look: export VK_ICD_FILENAMES=$icd" >&2
       fi ;;
  esac
  if have_nvidia_runtime; then exit 0; fi
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    export DEBIAN_FRONTEND=noninteractive
    # Bounded: a machine without a package mirror fails here in seconds, not after apt's retries.
    timeout 60 apt-get -o Acquire::Retries=0 -o Acquire::http::Timeout=15 update -qq >/dev/null 2>&1 || true
    timeout 300 apt-get install -y -qq libvulkan1 libglvnd0 libglx0 libegl1 >/dev/null 2>&1 || true
    ldconfig 2>/dev/null || true
    if have_nvidia_runtime; then exit 0; fi
  fi
  echo "garage_exp: an NVIDIA GPU is here ($icd) but not the Vulkan loader and GL dispatch libraries its driver needs: install libvulkan1 libglvnd0 libglx0 libegl1, then rerun." >&2
  exit 1
fi

have_mesa_ge_25() {
  local v
  v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
  [ -n "$v" ] && dpkg --compare-versions "$v" ge 25 && dpkg -s libvulkan1 >/dev/null 2>&1
}

if have_mesa_ge_25; then exit 0; fi

if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null; then
  echo "garage_exp: SAPIEN needs a Vulkan device: install libvulkan1 and mesa-vulkan-drivers >= 25 (Debian 12: from bookworm-backports) or a GPU driver, then rerun." >&2
  exit 1
fi

. /etc/os-release
if [ "${VERSION_CODENAME:-}" = bookworm ] && ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
  # Reuse the mirror this machine already uses instead of naming one.
  src=/etc/apt/sources.list.d/debian.sources
  uri=$(awk '/^URIs:/{print $2; exit}' "$src" 2>/dev/null || true)
  [ -n "$uri" ] || uri=$(awk '/^deb /{print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)
  key=$(awk '/^Signed-By:/{print $2; exit}' "$src" 2>/dev/null || echo /usr/share/keyrings/debian-archive-keyring.gpg)
  printf 'Types: deb\nURIs: %s\nSuites: bookworm-backports\nComponents: main\nSigned-By: %s\n' "$uri" "$key" \
    > /etc/apt/sources.list.d/garage-exp-backports.sources
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
if [ "${VERSION_CODENAME:-}" = bookworm ]; then
  apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
else
  apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
fi
have_mesa_ge_25 || { echo "garage_exp: installed Mesa is older than 25; SAPIEN may not find a device." >&2; }
