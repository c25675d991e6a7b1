#!/usr/bin/env bash
# Makes Debian's PostgreSQL server binaries available for the sweep's storage test, which
# starts its own throw-away cluster on 127.0.0.1 (no system service is used or changed).
# Idempotent: a no-op when initdb and pg_ctl are already installed.
set -euo pipefail

if ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1; then
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "ensure_postgres: PostgreSQL server binaries missing and apt-get unavailable;" \
       "install PostgreSQL (initdb, pg_ctl) under /usr/lib/postgresql/<version>/bin" >&2
  exit 1
fi
SUDO=()
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null 2>&1 || { echo "ensure_postgres: not root and no sudo; run as root: apt-get install -y postgresql" >&2; exit 1; }
  SUDO=(sudo)
fi
echo "ensure_postgres: installing Debian's postgresql package" >&2
"${SUDO[@]}" apt-get update -qq
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends postgresql >/dev/null
ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1 || { echo "ensure_postgres: install finished but pg_ctl is missing" >&2; exit 1; }
