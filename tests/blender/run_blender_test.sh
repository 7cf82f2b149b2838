#!/usr/bin/env bash
# The Blender round trip through the add-on (blender/clothdb_blender, docs/guide/blender.md),
# driven headless in Debian's Blender: builds a small database with the `clothdb` under test, then
# runs tests/blender/roundtrip.py inside `blender -b --factory-startup`. Exit 77 (CTest: Skipped)
# when Blender is not installed (CLOTHDB_BLENDER=1 scripts/setup.sh installs it).
# Usage: run_blender_test.sh CLOTHDB SOURCE_DIR WORK_DIR
set -euo pipefail
clothdb=$1 source=$2 work=$3
blender=${CLOTHDB_BLENDER_EXE:-$(command -v blender || true)}
if [ -z "$blender" ]; then
  echo "SKIP: no blender (CLOTHDB_BLENDER=1 scripts/setup.sh installs Debian's)"
  exit 77
fi
rm -rf "$work"
mkdir -p "$work"
# A 1-2 s precompute of the 200-vertex test skirt: a few batches, enough clips to list and edit.
"$clothdb" precompute "$source/tests/data/mpi_small.json" --db "$work/small.db" --epsilon 10 \
  --batch 4 --threads 1 --frames 400 --quiet --no-floor >"$work/precompute.log" 2>&1
# From another directory, so the add-on depends on nothing but the database (its stored scene).
cd "$work"
export CLOTHDB_EXE="$clothdb" CLOTHDB_TEST_DB="$work/small.db" CLOTHDB_ADDON_DIR="$source/blender"
"$blender" -b --factory-startup --python-exit-code 1 --python "$source/tests/blender/roundtrip.py" \
  >"$work/blender.log" 2>&1 || {
  cat "$work/blender.log"
  exit 1
}
grep -E "^(ok|FAIL)" "$work/blender.log" || true
grep -q "^all ok" "$work/blender.log"
