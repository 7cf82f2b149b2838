#!/usr/bin/env bash
# Checks the explorer's forecast against what happened: from the curve(s) of a run that converged
# (PREFIX.csv, written by `clothdb precompute --curve PREFIX`; a resumed run's curves in the order
# they ran), prints the forecast made at FRACTION (default 0.5) of the run's CPU time against the
# CPU time the run took. The forecast is replayed by `clothdb forecast` with the current model.
# Usage: scripts/forecast_check.sh CURVE.csv [MORE.csv ...] [FRACTION (default 0.5)]
set -euo pipefail
if [ "${1:-}" = "--help" ] || [ "${1:-}" = "-h" ] || [ $# -lt 1 ]; then
  sed -n '2,6p' "$0" | sed 's/^# \{0,1\}//'
  [ $# -ge 1 ]; exit
fi
cd "$(dirname "${BASH_SOURCE[0]}")/.."
curves=() fraction=0.5
for arg in "$@"; do
  case $arg in
    *.csv) curves+=("$arg") ;;
    *) fraction=$arg ;;
  esac
done
exec "${CLOTHDB_BUILD_DIR:-build}/cli/clothdb" forecast "${curves[@]}" --at "$fraction"
