#!/usr/bin/env bash
# PostgreSQL's server binaries for the cluster tests (tests/test_cluster.py, marker `cluster`): each test run
# starts its own throw-away server (initdb + pg_ctl on a free port), never the system's. Idempotent: does nothing
# when initdb is installed.
if compgen -G "/usr/lib/postgresql/*/bin/initdb" >/dev/null || command -v initdb >/dev/null 2>&1; then exit 0; fi
exec bash "$(dirname "$0")/apt_install.sh" postgresql "the cluster tests"
