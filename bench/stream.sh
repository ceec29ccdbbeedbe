#!/usr/bin/env bash
# Benchmark: what a live stream's checkpoints cost (bench/stream_bench.cpp; one case per process,
# cases alternated, medians reported): a 2-channel uint16 X x Y x Z stream sent plane by plane,
#   plain:   in one go, then finished;
#   suspend: suspended halfway (checkpoint + close), resumed by a plane of the first half sent
#            again, suspended again, then the second half, then finished.
# Results in docs/benchmarks.md, "Stream checkpoints".
#
# Usage: bash bench/stream.sh [REPEATS] [X] [Y] [Z]   (defaults: 5 repeats, 1024 x 1024 x 128)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
bench="$build/bench/stream_bench"
repeats="${1:-5}"
x="${2:-1024}"
y="${3:-1024}"
z="${4:-128}"
[ -x "$bench" ] || cmake --build "$build" --target stream_bench >/dev/null
field() { sed -n "s/.* $1=\([^ ]*\).*/\1/p" <<<"$2"; }

declare -a plain suspend
for ((i = 0; i < repeats; i++)); do
  plain+=("$("$bench" "$work" "$x" "$y" "$z" plain)")
  suspend+=("$("$bench" "$work" "$x" "$y" "$z" suspend)")
done
echo "stream ${x}x${y}x${z}, 2 channels uint16, ${repeats} runs each, medians (load $(loadavg)):"
for impl in plain suspend; do
  declare -n lines="$impl"
  out="$impl:"
  for key in create_ms first_half_ms first_half_mbps suspend_ms resume_replace_ms \
             suspend_again_ms second_half_ms second_half_mbps finish_ms; do
    values=()
    for line in "${lines[@]}"; do values+=("$(field "$key" "$line")"); done
    out+=" $key=$(median "${values[@]}")"
  done
  echo "$out"
done
