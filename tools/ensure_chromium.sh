#!/usr/bin/env bash
# Makes Debian's `chromium` available for the report's headless-browser test.
# Idempotent: a no-op when chromium is already on PATH. Only the distribution package is
# used (no browser downloads by playwright/pyppeteer), so it works behind a package mirror.
set -euo pipefail

if command -v chromium >/dev/null 2>&1; then
  exit 0
fi

if ! command -v apt-get >/dev/null 2>&1; then
  echo "ensure_chromium: chromium is not on PATH and apt-get is unavailable;" \
       "install a Chromium build that provides a 'chromium' command" >&2
  exit 1
fi

# sudo only when needed: CI containers usually run as root and often lack sudo.
SUDO=()
if [ "$(id -u)" -ne 0 ]; then
  if ! command -v sudo >/dev/null 2>&1; then
    echo "ensure_chromium: not root and sudo is missing; run as root:" \
         "apt-get install -y chromium" >&2
    exit 1
  fi
  SUDO=(sudo)
fi

echo "ensure_chromium: installing Debian's chromium package" >&2
"${SUDO[@]}" apt-get update -qq
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
command -v chromium >/dev/null 2>&1 || { echo "ensure_chromium: install finished but chromium is not on PATH" >&2; exit 1; }
