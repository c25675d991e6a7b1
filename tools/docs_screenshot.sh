#!/usr/bin/env bash
# A screenshot of the documentation site's home page, taken by Debian's headless Chromium:
# a look at the built site without a desktop (and what tests/docs/test_screenshot.py checks).
#
#   bash tools/docs_screenshot.sh [SITE_DIR (default site)] [OUT.png (default SITE_DIR/home.png)]
#
# Builds the site first (mkdocs build --strict) unless SITE_DIR already holds index.html.
# Installs chromium with tools/ensure_chromium.sh when it is missing. Nothing is fetched from
# the network: the site has no web fonts or CDN assets, and Chromium runs with its background
# networking and component updates off, in a throw-away profile.
set -euo pipefail
HERE=$(cd "$(dirname "$0")/.." && pwd)
SITE=${1:-site}
OUT=${2:-$SITE/home.png}
PY=${PYTHON:-$HERE/.venv/bin/python}

if [ ! -f "$SITE/index.html" ]; then
  (cd "$HERE" && NO_MKDOCS_2_WARNING=1 "$PY" -m mkdocs build --strict --quiet --site-dir "$(realpath -m "$SITE")")
fi
bash "$HERE/tools/ensure_chromium.sh"

profile=$(mktemp -d)
trap 'rm -rf "$profile"' EXIT
page="file://$(realpath "$SITE")/index.html"
mkdir -p "$(dirname "$OUT")"
out=$(realpath -m "$OUT")
# --virtual-time-budget lets the page's scripts settle before the picture is taken.
timeout 120 "$(command -v chromium)" --headless --no-sandbox --disable-gpu --disable-background-networking \
  --disable-component-update --no-first-run --disable-dev-shm-usage --hide-scrollbars \
  --user-data-dir="$profile" --window-size=1280,1000 --virtual-time-budget=3000 \
  --screenshot="$out" "$page" >/dev/null 2>&1
[ -s "$out" ] || { echo "docs_screenshot: chromium wrote no screenshot of $page" >&2; exit 1; }
echo "$out"
