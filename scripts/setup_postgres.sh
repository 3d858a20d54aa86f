#!/usr/bin/env bash
# PostgreSQL's server binaries for the cluster tests (tests/test_cluster.py, marker `cluster`): each test run
# starts its own throw-away server (initdb + pg_ctl on a free port), never the system's. Idempotent: does nothing
# when initdb is installed. Not fatal: without it only the cluster tests skip (and fail under make test).
set -uo pipefail

if compgen -G "/usr/lib/postgresql/*/bin/initdb" >/dev/null || command -v initdb >/dev/null 2>&1; then exit 0; fi
if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null; then
  echo "garage_exp: the cluster tests need PostgreSQL: apt-get install postgresql (as root), then rerun." >&2
  exit 0
fi
export DEBIAN_FRONTEND=noninteractive
if ! apt-get install -y -qq postgresql >/dev/null 2>&1; then
  apt-get update -qq && apt-get install -y -qq postgresql >/dev/null \
    || echo "garage_exp: could not install postgresql; the cluster tests will say so." >&2
fi
