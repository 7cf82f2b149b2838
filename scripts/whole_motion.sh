#!/usr/bin/env bash
# The whole-motion run (docs/guide/whole_motion.md): the demo skirt on all of CMU 01_01 + 01_03
# (motions/skirt_whole_motion.json, whose "graph" block fixes the motion graph), with its run
# settings fixed here rather than chosen for the result:
#  1. the garment's error floor on that graph (`clothdb floor`, kept in $OUT/floor.json so that a
#     rerun reuses it and explores with the same epsilon);
#  2. epsilon = 1.5 x the floor, at most 14 mm; the demo's codec bound (0.1 mm per coordinate);
#     steering as the demo (K = 10 frames, D = 10 mm: the scene's "steering" block);
#  3. `clothdb precompute` into $DB for a budget of $CPU_HOURS CPU-hours, the error curve beside it.
#     The floor is measured once, in step 1 (--no-floor: the same measurement again would cost as
#     much); rerunning the script resumes the exploration.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BUILD_DIR=${CLOTHDB_BUILD_DIR:-build}
OUT=${CLOTHDB_WHOLE_OUT:-out/whole_motion}
DB=${CLOTHDB_WHOLE_DB:-$OUT/whole.db}
CPU_HOURS=${CLOTHDB_WHOLE_CPU_HOURS:-2}
SCENE=motions/skirt_whole_motion.json
CLOTHDB="$BUILD_DIR/cli/clothdb"
mkdir -p "$OUT"
if [ ! -f "$OUT/floor.json" ]; then
  "$CLOTHDB" floor "$SCENE" --out "$OUT/floor.json"
fi
FLOOR_MM=$(sed -n 's/.*"floor_mm": *\([0-9.eE+-]*\).*/\1/p' "$OUT/floor.json" | head -n 1)
if [ -z "$FLOOR_MM" ]; then
  echo "whole_motion.sh: $OUT/floor.json: no floor_mm in it; delete it to measure again" >&2
  exit 1
fi
EPSILON_MM=$(awk -v f="$FLOOR_MM" 'BEGIN { e = 1.5 * f; if (e > 14) e = 14; printf "%.2f", e }')
echo "whole_motion.sh: error floor $FLOOR_MM mm, epsilon $EPSILON_MM mm (1.5x the floor, at most 14)"
"$CLOTHDB" precompute "$SCENE" --db "$DB" --epsilon "$EPSILON_MM" --position-bound 0.1 \
  --no-floor --cpu-hours "$CPU_HOURS" --curve "$OUT/error_curve" --quiet
"$CLOTHDB" db info "$DB"
