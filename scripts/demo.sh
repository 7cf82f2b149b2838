#!/usr/bin/env bash
# Set-up (packages, configure, build) and the demo: a skirt on CMU mocap 01_01 simulated with XPBD,
# written for Blender with previews, then the solvers' speed against error on the hard cases.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
source scripts/setup.sh
BUILD_DIR=${CLOTHDB_BUILD_DIR:-build}
OUT=${CLOTHDB_DEMO_OUT:-out/demo}
"$BUILD_DIR"/cli/clothdb simulate motions/skirt_walk.json --clip 01_01 --frames 150 --out "$OUT/skirt_walk"
"$BUILD_DIR"/cli/clothdb bench solvers --quick --frames 30 --out "$OUT/bench-solvers"
echo "demo: results in $OUT (previews: $OUT/skirt_walk/previews, plots: $OUT/bench-solvers/*.svg)"
