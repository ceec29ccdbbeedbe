#!/usr/bin/env bash
# Fuzzes one harness with libFuzzer for a bounded time.
# Usage: bash fuzz/run.sh [SECONDS=120] [JOBS=1] [HARNESS=tiff_ome_fuzzer]
#   HARNESS: tiff_ome_fuzzer (TIFF + OME-XML), zarr_metadata_fuzzer, chunk_codec_fuzzer,
#   zarr_store_fuzzer (OME-Zarr; input formats in fuzz/zarr_fuzz_inputs.h), dataset_json_fuzzer
#   (stream requests, watch sidecars), ws_message_fuzzer (WebSocket client messages).
# Builds with clang (+ASan/UBSan, libFuzzer coverage) into build-fuzz/. The TIFF harness seeds
# from fuzz/seeds and fuzz/regressions (plus small files of ../shared/testdata when present), the
# Zarr harnesses from fuzz/zarr/seeds/NAME and fuzz/zarr/regressions/NAME (NAME = the harness
# without "_fuzzer"), dataset_json_fuzzer from fuzz/seeds-json, ws_message_fuzzer from
# fuzz/ws/seeds and fuzz/ws/regressions. New corpus entries go to fuzz/corpus-run/HARNESS/,
# crashes to fuzz/crashes/. Turn every crash into a regression: copy it into the harness's
# regressions folder (tests/io/bad_input_test.cpp, tests/io/zarr_fuzz_replay_test.cpp and
# tests/protocol/ws_messages_test.cpp replay them).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
seconds="${1:-120}"
jobs="${2:-1}"
harness="${3:-tiff_ome_fuzzer}"
build="$root/build-fuzz"
san="-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
CC=clang CXX=clang++ cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DOCTOSCOPE_FUZZ=ON -DOCTOSCOPE_BUILD_TESTS=OFF \
  -DCMAKE_CXX_FLAGS="-fsanitize=fuzzer-no-link $san" -DCMAKE_C_FLAGS="$san" \
  -DCMAKE_EXE_LINKER_FLAGS="$san" >/dev/null
cmake --build "$build" --target "$harness" -j "$(nproc)"

corpus="$root/fuzz/corpus-run/$harness"
mkdir -p "$corpus" "$root/fuzz/crashes"
source "$root/fuzz/seed_dirs.sh"
mapfile -t seeds < <(seed_dirs "$harness")
testdata="$root/../shared/testdata"
if [ "$harness" = tiff_ome_fuzzer ] && [ -d "$testdata" ]; then
  # Small real files make good seeds (big ones only slow each run down).
  mkdir -p "$build/testdata-seeds"
  find "$testdata" -type f \( -name '*.tif' -o -name '*.tiff' -o -name '*.ome' \) -size -200k \
    -exec cp -f {} "$build/testdata-seeds/" \;
  seeds+=("$build/testdata-seeds")
fi
cd "$build"  # libFuzzer writes fuzz-N.log into the working directory.
ASAN_OPTIONS=detect_leaks=1:allocator_may_return_null=1 \
  "$build/fuzz/$harness" "$corpus" "${seeds[@]}" -max_total_time="$seconds" -jobs="$jobs" \
  -workers="$jobs" -rss_limit_mb=2048 -max_len=262144 -timeout=10 \
  -artifact_prefix="$root/fuzz/crashes/$harness-" -print_final_stats=1
