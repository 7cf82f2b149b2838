#!/usr/bin/env bash
# Set-up (packages, configure, build) and the demo, the main job on the bundled motions:
#  1. the motion graph of CMU 01_01 + 01_03 (Kovar et al. 2002), written into the database and drawn
#     as SVG;
#  2. the secondary cloth graph of a 3,000-vertex skirt explored into one SQLite database
#     (Kim et al. 2013) with epsilon 8 mm (1.4x the garment's measured error floor, 5.7 mm) for a
#     budget of at most 0.2 CPU-hours (it converges in about 2 CPU-minutes);
#  3. the database checked, summarised, and played back along a random path.
# Rerunning resumes the exploration where it stopped (CLOTHDB_DEMO_FRESH=1 starts over).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
source scripts/setup.sh
BUILD_DIR=${CLOTHDB_BUILD_DIR:-build}
OUT=${CLOTHDB_DEMO_OUT:-out/demo}
CPU_HOURS=${CLOTHDB_DEMO_CPU_HOURS:-0.2}
# Codec bound per coordinate in mm for a new database. 0.1 mm, not the codec's default 0.5 mm:
# on the skirt's 11-26 mm edges 0.5 mm of quantisation adds up to 10 % edge strain to what is
# played, 0.1 mm about 2 % (docs/notebook/BENCHMARKS.md, "Contact rounds"). Empty: the codec's default.
BOUND=${CLOTHDB_DEMO_POSITION_BOUND-0.1}
BOUND_ARGS=()
if [ -n "$BOUND" ]; then BOUND_ARGS=(--position-bound "$BOUND"); fi
CLOTHDB="$BUILD_DIR/cli/clothdb"
mkdir -p "$OUT"
if [ "${CLOTHDB_DEMO_FRESH:-0}" = 1 ]; then rm -f "$OUT"/skirt.db*; fi

# The graph goes into the database (a rerun finds it there already); precompute explores on it.
"$CLOTHDB" graph build motions/cmu_walk.json --clips 01_01,01_03 --out "$OUT/graph.json" --db "$OUT/skirt.db" \
  "${BOUND_ARGS[@]}"
"$CLOTHDB" graph show "$OUT/skirt.db" --summary --svg "$OUT/graph.svg"
"$CLOTHDB" precompute motions/skirt_walk.json --db "$OUT/skirt.db" "${BOUND_ARGS[@]}" \
  --epsilon 8 --cpu-hours "$CPU_HOURS" --curve "$OUT/error_curve"
"$CLOTHDB" db check "$OUT/skirt.db"
"$CLOTHDB" db info "$OUT/skirt.db"
"$CLOTHDB" play "$OUT/skirt.db" --path random --seconds 6 --out "$OUT/play"
# The forecasts `precompute` made at a quarter, half and three quarters of its run against the CPU
# time the run took (docs/notebook/convergence.md, "The forecast").
"$CLOTHDB" forecast "$OUT/error_curve.csv" --at 0.25,0.5,0.75
echo
echo "demo: database $OUT/skirt.db; error curve $OUT/error_curve.svg (.csv);"
echo "      motion graph $OUT/graph.svg; playback $OUT/play (PC2 + OBJ for Blender, PNG previews)"
echo "      watch it play in the browser: $CLOTHDB view $OUT/skirt.db (docs/guide/viewer.md)"
