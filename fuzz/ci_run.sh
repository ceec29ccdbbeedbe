#!/usr/bin/env bash
# One bounded libFuzzer run, as a ctest entry (fuzz/tests.cmake): fuzzes HARNESS (a binary of the
# clang fuzz build) for SECONDS, starting from its seeds and regressions (fuzz/seed_dirs.sh), with
# a fresh working corpus under WORKDIR. Exit 0 when nothing was found; otherwise libFuzzer's
# status, and the input that failed is kept under WORKDIR/crashes/ — turn it into a regression
# (fuzz/README.md: fix the bug, copy the file into the harness's regressions folder).
# Usage: bash fuzz/ci_run.sh HARNESS_BINARY SECONDS WORKDIR
set -euo pipefail
binary="$1"
seconds="$2"
work="$3"
harness="$(basename "$binary")"
source "$(dirname "${BASH_SOURCE[0]}")/seed_dirs.sh"
mapfile -t seeds < <(seed_dirs "$harness")
if [ ! -x "$binary" ]; then
  echo "ci_run: $binary is missing (the clang fuzz build failed or was not built: cmake --build)" >&2
  exit 1
fi
rm -rf "$work/corpus"
mkdir -p "$work/corpus" "$work/crashes"
cd "$work"  # libFuzzer writes its logs into the working directory.
status=0
ASAN_OPTIONS=detect_leaks=1:allocator_may_return_null=1 \
  "$binary" "$work/corpus" "${seeds[@]}" -max_total_time="$seconds" -rss_limit_mb=2048 \
  -max_len=262144 -timeout=10 -artifact_prefix="$work/crashes/" -print_final_stats=1 \
  2>"$work/fuzz.log" || status=$?
grep -E '^(stat::number_of_executed_units|stat::new_units_added|Done [0-9]+ runs)' \
  "$work/fuzz.log" || true
if [ "$status" -ne 0 ]; then
  tail -60 "$work/fuzz.log"
  echo "ci_run: $harness found a failing input: $(ls "$work/crashes/" | tr '\n' ' ')" >&2
  echo "ci_run: fix it, then copy the input into one of: ${seeds[*]}" >&2
fi
exit "$status"
