#!/usr/bin/env bash
# Bring the machine to a Vulkan device SAPIEN 3 accepts. On CPU-only Debian 12 that is
# Mesa >= 25 lavapipe from bookworm-backports (Mesa 22.3 lacks descriptorBindingPartiallyBound).
# Idempotent: does nothing when a suitable lavapipe (or any GPU ICD) is already installed.
set -euo pipefail

have_mesa_ge_25() {
  local v
  v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
  [ -n "$v" ] && dpkg --compare-versions "$v" ge 25 && dpkg -s libvulkan1 >/dev/null 2>&1
}

if have_mesa_ge_25; then exit 0; fi
if ls /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json >/dev/null 2>&1; then
  exit 0  # a GPU driver is present; SAPIEN uses it
fi

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
