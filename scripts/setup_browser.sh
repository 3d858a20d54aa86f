#!/usr/bin/env bash
# A browser for the tests that look at the MLflow UI as a user does (tests/test_mlflow_ui.py, marker `browser`).
# Playwright drives Debian's chromium: its own browser download cannot work here. Idempotent: does nothing when
# chromium is installed.
if command -v chromium >/dev/null 2>&1; then exit 0; fi
exec bash "$(dirname "$0")/apt_install.sh" chromium "the browser tests"
