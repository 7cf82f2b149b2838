#!/usr/bin/env bash
# CTest's `viewer_browser` (label browser): `clothdb view` in headless Chromium (viewer_test.mjs).
# Exit 77 (CTest: Skipped, never Passed) when what it needs is missing: Chromium (Debian's
# `chromium`: scripts/setup.sh installs it with CLOTHDB_BROWSER=1, as .ci/run does), Node, or the
# viewer's npm packages (scripts/setup.sh runs `npm ci` in viewer/).
# MODE `server` (CTest's viewer_server): only the checks that need no browser; needs Node only.
#   run_viewer_test.sh CLOTHDB MAKE_DEMO_DB SOURCE_DIR WORK_DIR [server]
set -euo pipefail
clothdb=$1 make_db=$2 src=$3 work=$4 mode=${5:-browser}
chromium=${CLOTHDB_CHROMIUM:-/usr/bin/chromium}
skip() { echo "SKIPPED: $*" >&2; exit 77; }
command -v node >/dev/null || skip "no node"
if [ "$mode" != server ]; then
  [ -x "$chromium" ] || skip "no Chromium at $chromium (CLOTHDB_BROWSER=1 scripts/setup.sh installs it)"
  [ -d "$src/viewer/node_modules/playwright-core" ] && [ -d "$src/viewer/node_modules/three" ] ||
    skip "no viewer/node_modules (scripts/setup.sh runs npm ci there when npm is installed)"
fi
rm -rf "$work"
mkdir -p "$work"
# The synthetic database of the runtime's tests: 576 vertices, nodes with two successors.
"$make_db" "$work/demo.clothdb" >/dev/null
exec node "$src/tests/browser/viewer_test.mjs" "$clothdb" "$work/demo.clothdb" "$work" "$mode"
