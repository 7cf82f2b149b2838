#!/usr/bin/env bash
# Set-up (packages, configure, build) and the whole test suite through CTest.
# CLOTHDB_LONG=1 also runs the long tests (fuzzers, slow sweeps).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
source scripts/setup.sh
BUILD_DIR=${CLOTHDB_BUILD_DIR:-build}
if [ "${CLOTHDB_LONG:-0}" = 1 ]; then
  ctest --test-dir "$BUILD_DIR" --output-on-failure -j"$(nproc)"
else
  ctest --test-dir "$BUILD_DIR" --output-on-failure -j"$(nproc)" -LE long
fi
