#!/usr/bin/env bash
# Benchmark: the page cache (server/paging) against the plainest code doing the same work, both
# measured in the same run (bench/paging_bench.cpp; one case per process, implementations
# alternated, medians reported):
#   fresh:     pin PAGES never-written 1 MiB pages, mark dirty, fill them  vs  malloc + fill.
#   construct: a construction-like loop (pin, fill, PASSES read passes, unpin) over PAGES fresh
#              1 MiB pages with a budget of BUDGET pages, then Flush, without and with
#              write-behind  vs  one buffer + the same work + pwrite per page + fsync. Run once
#              with the real page file and once with writes throttled to an emulated MBPS disk.
#
# Usage: bash bench/paging.sh [REPEATS] [PAGES] [BUDGET] [PASSES] [MBPS]
#   defaults: 5 repeats, 512 pages (512 MiB), budget 64 pages, 8 passes, 400 MB/s.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
bin="$build/bench/paging_bench"
repeats="${1:-5}"
pages="${2:-512}"
budget="${3:-64}"
passes="${4:-8}"
mbps="${5:-400}"
work="${OCTOSCOPE_BENCH_DIR:-$root/out/bench}"
mkdir -p "$work"
[ -x "$bin" ] || cmake --build "$build" --target paging_bench >/dev/null

field() { sed -n "s/.* $1=\([^ ]*\).*/\1/p" <<<"$2"; }
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }

# run_cases NAME ARGS... : alternates the implementations given in IMPLS, REPEATS times, and
# stores every line in lines_<impl>.
run_cases() {
  local impl line
  for impl in "${impls[@]}"; do eval "lines_${impl//-/_}=()"; done
  for _ in $(seq "$repeats"); do
    for impl in "${impls[@]}"; do
      line=$("$bin" "$@" "$impl")
      eval "lines_${impl//-/_}+=(\"\$line\")"
    done
  done
}
# stat IMPL KEY: the median of KEY over IMPL's lines.
stat() {
  local name="lines_${1//-/_}[@]" values=() line
  for line in "${!name}"; do values+=("$(field "$2" "$line")"); done
  median "${values[@]}"
}

impls=(baseline cache)
run_cases fresh "$work" "$pages" 1
printf 'fresh: %d never-written 1 MiB pages pinned, marked dirty and filled (median of %d)\n' \
  "$pages" "$repeats"
printf '  %-10s %9s %9s %9s\n' impl wall_s user_s sys_s
for impl in "${impls[@]}"; do
  printf '  %-10s %9.4f %9.4f %9.4f\n' "$impl" "$(stat "$impl" seconds)" \
    "$(stat "$impl" user_seconds)" "$(stat "$impl" sys_seconds)"
done
printf '  ratio cache/baseline: wall %.2f  cpu %.2f\n' \
  "$(awk -v a="$(stat cache seconds)" -v b="$(stat baseline seconds)" 'BEGIN {print a / b}')" \
  "$(awk -v a="$(stat cache user_seconds)" -v b="$(stat cache sys_seconds)" \
         -v c="$(stat baseline user_seconds)" -v d="$(stat baseline sys_seconds)" \
         'BEGIN {print (a + b) / (c + d)}')"

impls=(baseline cache cache-wb)
for rate in 0 "$mbps"; do
  run_cases construct "$work" "$pages" "$budget" 1 "$passes" "$rate"
  if [ "$rate" = 0 ]; then disk="the page file as fast as the OS takes it"; else disk="writes throttled to $rate MB/s"; fi
  printf '\nconstruct: %d pages of 1 MiB through a %d-page budget, %d passes each, %s (median of %d)\n' \
    "$pages" "$budget" "$passes" "$disk" "$repeats"
  printf '  %-10s %9s %9s %9s %9s %9s %14s\n' impl total_s loop_s flush_s cpu_s ratio dirty_at_flush
  base=$(stat baseline seconds)
  for impl in "${impls[@]}"; do
    total=$(stat "$impl" seconds)
    printf '  %-10s %9.4f %9.4f %9.4f %9.4f %9.2f %14s\n' "$impl" "$total" "$(stat "$impl" loop_seconds)" \
      "$(stat "$impl" flush_seconds)" \
      "$(awk -v a="$(stat "$impl" user_seconds)" -v b="$(stat "$impl" sys_seconds)" 'BEGIN {print a + b}')" \
      "$(awk -v a="$total" -v b="$base" 'BEGIN {print a / b}')" "$(stat "$impl" dirty_at_flush)"
  done
done
