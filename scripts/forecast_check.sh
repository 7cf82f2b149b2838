#!/usr/bin/env bash
# Checks the explorer's forecast against what happened: from a precompute curve (PREFIX.csv,
# written by `clothdb precompute --curve PREFIX`) of a run that started a new database and
# converged, prints the forecast made at about half of the run's CPU time (the forecast_cpu_hours
# column: the forecast made from the curve up to that row) against the CPU time the run took.
# Usage: scripts/forecast_check.sh CURVE.csv [FRACTION (default 0.5)]
set -euo pipefail
if [ "${1:-}" = "--help" ] || [ "${1:-}" = "-h" ] || [ $# -lt 1 ]; then
  sed -n '2,6p' "$0" | sed 's/^# \{0,1\}//'
  [ $# -ge 1 ]; exit
fi
csv=$1 fraction=${2:-0.5}
[ -f "$csv" ] || { echo "forecast check: $csv: no such file" >&2; exit 2; }
awk -F, -v fraction="$fraction" -v file="$csv" '
  NR == 1 {
    for (i = 1; i <= NF; ++i) col[$i] = i
    if (!("forecast_cpu_hours" in col) || !("cpu_seconds" in col) || !("dead_ends" in col)) {
      printf "forecast check: %s: no forecast_cpu_hours, cpu_seconds or dead_ends column\n", file
      bad = 1; exit
    }
    next
  }
  { ++n; t[n] = $col["cpu_seconds"]; f[n] = $col["forecast_cpu_hours"]; d[n] = $col["dead_ends"];
    frames[n] = $col["frames"] }
  END {
    if (bad) exit 2
    if (n == 0) { printf "forecast check: %s: no rows\n", file; exit 2 }
    if (frames[1] != 0) {
      printf "forecast check: not made: %s is the curve of a resumed run (the check needs a run from a new database)\n", file
      exit 0
    }
    if (d[n] != 0) {
      printf "forecast check: not made: the run did not converge (%d dead ends left at %.0f CPU-s)\n", d[n], t[n]
      exit 0
    }
    total = t[n]; want = fraction * total; best = 1
    for (i = 1; i <= n; ++i) if ((t[i] - want)^2 < (t[best] - want)^2) best = i
    if (f[best] == "") {
      printf "forecast check: at %.0f %% of the run (%.0f of %.0f CPU-s) there was no forecast (none: fewer than 4 batches in the last half of the curve, or dead ends + unexplored ways out not falling)\n",
        100 * t[best] / total, t[best], total
      exit 0
    }
    forecast = 3600 * f[best]
    printf "forecast check: at %.0f %% of the run (%.0f CPU-s) the forecast was %.0f CPU-s to converge; it took %.0f CPU-s (forecast %+.0f %%; target within 30 %%)\n",
      100 * t[best] / total, t[best], forecast, total, 100 * (forecast - total) / total
  }' "$csv"
