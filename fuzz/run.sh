#!/usr/bin/env bash
# Fuzzes the TIFF + OME-XML path (or another harness) with libFuzzer for a bounded time.
# Usage: bash fuzz/run.sh [SECONDS=120] [JOBS=1] [FUZZER=tiff_ome_fuzzer|dataset_json_fuzzer]
# Builds with clang (+ASan/UBSan, libFuzzer coverage) into build-fuzz/, seeds from fuzz/seeds and
# fuzz/regressions (plus small files of ../shared/testdata when present), writes new corpus
# entries to fuzz/corpus-run/ and crashes to fuzz/crashes/. Turn every crash into a regression:
# copy it into fuzz/regressions/ (tests/io/fuzz_regression_test.cpp replays that folder in ctest).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
seconds="${1:-120}"
jobs="${2:-1}"
fuzzer="${3:-tiff_ome_fuzzer}"
build="$root/build-fuzz"
san="-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
CC=clang CXX=clang++ cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DOCTOSCOPE_FUZZ=ON -DOCTOSCOPE_BUILD_TESTS=OFF \
  -DCMAKE_CXX_FLAGS="-fsanitize=fuzzer-no-link $san" -DCMAKE_C_FLAGS="$san" \
  -DCMAKE_EXE_LINKER_FLAGS="$san" >/dev/null
cmake --build "$build" --target "$fuzzer" -j "$(nproc)"

corpus="$root/fuzz/corpus-run"
seeds=("$root/fuzz/seeds" "$root/fuzz/regressions")
if [ "$fuzzer" = dataset_json_fuzzer ]; then
  corpus="$root/fuzz/corpus-run-json"
  seeds=("$root/fuzz/seeds-json")
fi
mkdir -p "$corpus" "$root/fuzz/crashes"
testdata="$root/../shared/testdata"
if [ -d "$testdata" ] && [ "$fuzzer" = tiff_ome_fuzzer ]; then
  # Small real files make good seeds (big ones only slow each run down).
  mkdir -p "$build/testdata-seeds"
  find "$testdata" -type f \( -name '*.tif' -o -name '*.tiff' -o -name '*.ome' \) -size -200k \
    -exec cp -f {} "$build/testdata-seeds/" \;
  seeds+=("$build/testdata-seeds")
fi
cd "$build"  # libFuzzer writes fuzz-N.log into the working directory.
ASAN_OPTIONS=detect_leaks=1:allocator_may_return_null=1 \
  "$build/fuzz/$fuzzer" "$corpus" "${seeds[@]}" -max_total_time="$seconds" -jobs="$jobs" \
  -workers="$jobs" -rss_limit_mb=2048 -max_len=262144 -timeout=10 \
  -artifact_prefix="$root/fuzz/crashes/" -print_final_stats=1
