#!/usr/bin/env bash
# Set-up on a fresh Debian machine: installs the missing Debian packages (as root), configures and
# builds Release with CMake into ./build. Sourced by scripts/demo.sh and scripts/test.sh.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# libopenblas0-serial: single-threaded OpenBLAS, which update-alternatives makes libblas.so.3 and
# liblapack.so.3 on install; on it Newton's "cholmod-supernodal" factorises the 3k skirt 3-4x
# faster than on the reference BLAS (docs/notebook/BENCHMARKS.md, "Newton on seed 004's grids"). The
# serial build, not pthread: the solvers choose their own threads. python3: the docs checks
# (scripts/results.py, scripts/guide_examples.sh), standard library only.
PACKAGES=(cmake g++ make pkg-config libeigen3-dev libomp-dev libassimp-dev assimp-testmodels
  libsqlite3-dev libzstd-dev libcli11-dev nlohmann-json3-dev libsuitesparse-dev libpng-dev
  libgtest-dev libosmesa6-dev libglu1-mesa-dev clang-14 libclang-rt-14-dev libopenmpi-dev openmpi-bin
  libmeshoptimizer-dev libopenblas0-serial python3 libcpp-httplib-dev)
# Not installed here, as no test needs them: `blender` and `python3-numpy` (its glTF exporter
# imports numpy, which Debian's blender package does not pull in) only remake the Blender-written
# motion fixtures of tests/data/blender/ (scripts/make_blender_fixtures.py).
# The browser test of `clothdb view` (tests/browser/) needs Debian's Chromium (about 100 MB more):
# only when asked, as .ci/run does. Without it that test is skipped.
if [ "${CLOTHDB_BROWSER:-0}" = 1 ]; then PACKAGES+=(chromium); fi
# The Blender round trip's test (tests/blender/, the add-on in blender/) needs Debian's Blender
# (about 300 MB more): only when asked, as .ci/run does. Without it that test is skipped.
if [ "${CLOTHDB_BLENDER:-0}" = 1 ]; then PACKAGES+=(blender); fi
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    echo "setup: installing ${missing[*]}" >&2
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    echo "setup: missing Debian packages; install them with:" >&2
    echo "  sudo apt-get install ${missing[*]}" >&2
    exit 1
  fi
fi

# The viewer's page (`clothdb view`) draws with three.js, and its browser test drives Chromium with
# playwright-core: both from npm, pinned by viewer/package-lock.json, into viewer/node_modules.
# `npm ci` runs only when the lock file changed since the last install; without npm the C++ build
# goes on, the viewer serves a page saying three.js is missing, and the browser test is skipped.
if [ -f viewer/package-lock.json ]; then
  if ! command -v npm >/dev/null; then
    echo "setup: npm not found: skipping viewer/node_modules (three.js for clothdb view)" >&2
  elif ! cmp -s viewer/package-lock.json viewer/node_modules/.clothdb-installed-lock; then
    echo "setup: npm ci in viewer/ (three.js, playwright-core)" >&2
    (cd viewer && npm ci --no-audit --no-fund >/dev/null) &&
      cp viewer/package-lock.json viewer/node_modules/.clothdb-installed-lock ||
      echo "setup: npm ci in viewer/ failed: clothdb view will say three.js is missing" >&2
  fi
  # The page and the parts of three.js it uses in one minified module (esbuild): the browser
  # compiles 0.56 MB instead of 2.1 MB (docs/notebook/viewer.md). clothdb view serves it while it
  # is at least as new as viewer.js, else viewer.js itself.
  if [ -x viewer/node_modules/.bin/esbuild ] &&
    { [ ! -f viewer/dist/viewer.js ] || [ viewer/viewer.js -nt viewer/dist/viewer.js ] ||
      [ viewer/package-lock.json -nt viewer/dist/viewer.js ]; }; then
    (cd viewer && npm run --silent bundle) ||
      echo "setup: bundling viewer/ failed: clothdb view serves viewer.js unbundled (slower to load)" >&2
  fi
fi

BUILD_DIR=${CLOTHDB_BUILD_DIR:-build}
JOBS=$(nproc)
cmake -S . -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build "$BUILD_DIR" -j"$JOBS"
