#!/usr/bin/env bash
# apt_install.sh PACKAGE WHAT: install Debian's PACKAGE, which WHAT needs (the setup_*.sh scripts check first
# whether it is there). Not fatal: without root or apt, or when apt fails, one line says what to do, and only
# the tests that need it skip (and fail under make test).
set -uo pipefail
package=$1 what=$2
if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null; then
  echo "garage_exp: $what need $package: apt-get install $package (as root), then rerun." >&2
  exit 0
fi
export DEBIAN_FRONTEND=noninteractive
if ! apt-get install -y -qq "$package" >/dev/null 2>&1; then
  apt-get update -qq && apt-get install -y -qq "$package" >/dev/null \
    || echo "garage_exp: could not install $package; $what will say so." >&2
fi
