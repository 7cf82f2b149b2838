#!/usr/bin/env bash
# Builds the decoder fuzz target with clang's libFuzzer (+ AddressSanitizer and UBSan) and runs it.
# Usage: run_fuzz_decoder.sh CLANGXX SOURCE_DIR WORK_DIR SECONDS
# The corpus in WORK_DIR/corpus is kept between runs; crashes are written to WORK_DIR/artifacts.
set -euo pipefail
CXX=$1 SRC=$2 WORK=$3 SECONDS_TO_RUN=$4
mkdir -p "$WORK/corpus" "$WORK/artifacts"
SOURCES=("$SRC/database/codec/codec.cpp" "$SRC/database/codec/codec_v2.cpp" "$SRC/database/codec/codec_v3.cpp" "$SRC/database/codec/contract.cpp"
  "$SRC/database/format/checksum.cpp" "$SRC/database/format/status.cpp")
FLAGS=(-std=c++20 -g -O1 -ffp-contract=off -I"$SRC")
"$CXX" "${FLAGS[@]}" -DCLOTHDB_FUZZ_SEEDS "$SRC/tests/fuzz/fuzz_decoder.cpp" "${SOURCES[@]}" \
  -lzstd -o "$WORK/fuzz_decoder_seeds"
"$WORK/fuzz_decoder_seeds" "$WORK/corpus"
"$CXX" "${FLAGS[@]}" -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
  "$SRC/tests/fuzz/fuzz_decoder.cpp" "${SOURCES[@]}" -lzstd -o "$WORK/fuzz_decoder"
"$WORK/fuzz_decoder" -max_total_time="$SECONDS_TO_RUN" -rss_limit_mb=2048 -timeout=20 \
  -print_final_stats=1 -artifact_prefix="$WORK/artifacts/" "$WORK/corpus"
