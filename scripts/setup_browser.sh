#!/usr/bin/env bash
# A browser for the tests that look at the MLflow UI as a user does (tests/test_mlflow_ui.py, marker `browser`).
# Playwright drives Debian's chromium: its own browser download cannot work here. Idempotent: does nothing when
# chromium is installed. Not fatal: without it only the browser tests skip (and fail under make test).
set -uo pipefail

if command -v chromium >/dev/null 2>&1; then exit 0; fi
if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null; then
  echo "garage_exp: the browser tests need chromium: apt-get install chromium (as root), then rerun." >&2
  exit 0
fi
export DEBIAN_FRONTEND=noninteractive
if ! apt-get install -y -qq chromium >/dev/null 2>&1; then
  apt-get update -qq && apt-get install -y -qq chromium >/dev/null \
    || echo "garage_exp: could not install chromium; the browser tests will say so." >&2
fi
