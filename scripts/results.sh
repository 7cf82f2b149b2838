#!/usr/bin/env bash
# docs/results/*.json -> docs/RESULTS.md (scripts/results.py; never runs a benchmark).
#   scripts/results.sh           write docs/RESULTS.md
#   scripts/results.sh --check   exit 1 if docs/RESULTS.md differs from what would be written
#   scripts/results.sh --help    all options
set -euo pipefail
exec python3 "$(dirname "${BASH_SOURCE[0]}")/results.py" "$@"
