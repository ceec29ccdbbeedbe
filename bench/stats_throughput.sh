#!/usr/bin/env bash
# Benchmark: `octoscope info --stats` throughput on an uncompressed >= 1 GB OME-TIFF, as a ratio
# against `cat FILE >/dev/null` on the same file in the same run (both from the page cache: the
# file is read once before timing; this measures our per-byte cost, not the disk).
# Also checks the statistics against the demo generator's own (computed from the generated voxels,
# not from the file), so the speed figure comes with its error.
#
# Usage: bash bench/stats_throughput.sh [SIZE_X,Y,Z] [CHANNELS] [REPEATS]
#   default 1024,1024,256 x 2 channels uint16 = 1 GiB, 3 repeats (median reported).
#   OCTOSCOPE_COMPARE_BIN=/path/to/other/octoscope also times that binary (e.g. an older commit)
#   in the same alternation and reports its ratio too.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
size="${1:-1024,1024,256}"
channels="${2:-2}"
repeats="${3:-3}"

file="$work/stats-bench.ome.tif"
reference="$work/stats-bench.reference.json"
if [ ! -f "$file" ] || [ ! -f "$reference" ] || [ "$(cat "$work/stats-bench.params" 2>/dev/null)" != "$size $channels" ]; then
  echo "writing $size x $channels channels uncompressed demo specimen ..." >&2
  "$bin" demo --out "$work" --name stats-bench --size "$size" --channels "$channels" \
    --compression none --stats-json "$reference" >/dev/null
  echo "$size $channels" > "$work/stats-bench.params"
fi
bytes=$(stat -c %s "$file")

load_before=$(loadavg)  # The machine is shared: say how busy it was.
cat "$file" > /dev/null  # Warm the page cache once.
compare="${OCTOSCOPE_COMPARE_BIN:-}"
cat_s=(); stats_s=(); compare_s=()
for _ in $(seq "$repeats"); do
  t0=$(now); cat "$file" > /dev/null; t1=$(now)
  "$bin" info --stats --json "$file" > "$work/stats-bench.out.json"; t2=$(now)
  cat_s+=("$(awk -v a="$t0" -v b="$t1" 'BEGIN {print b - a}')")
  stats_s+=("$(awk -v a="$t1" -v b="$t2" 'BEGIN {print b - a}')")
  if [ -n "$compare" ]; then
    t3=$(now); "$compare" info --stats --json "$file" > /dev/null; t4=$(now)
    compare_s+=("$(awk -v a="$t3" -v b="$t4" 'BEGIN {print b - a}')")
  fi
done
cat_med=$(median "${cat_s[@]}")
stats_med=$(median "${stats_s[@]}")
cat_mbs=$(awk -v b="$bytes" -v s="$cat_med" 'BEGIN {print b / s / 1e6}')
stats_mbs=$(awk -v b="$bytes" -v s="$stats_med" 'BEGIN {print b / s / 1e6}')
ratio=$(awk -v a="$stats_mbs" -v b="$cat_mbs" 'BEGIN {print a / b}')

# Error against the generator's statistics: max |difference| over channels of min, max and mean.
error=$(python3 - "$reference" "$work/stats-bench.out.json" <<'PY'
import json, sys
ref, got = (json.load(open(p)) for p in sys.argv[1:3])
print(max(abs(a - b) for k in ("min", "max", "mean") for a, b in zip(ref[k], got[k])))
PY
)

printf 'file: %s (%d bytes)\n' "$file" "$bytes"
printf 'cat:          %8.1f MB/s  (median of %d: %s s)\n' "$cat_mbs" "$repeats" "$cat_med"
printf 'info --stats: %8.1f MB/s  (median of %d: %s s)\n' "$stats_mbs" "$repeats" "$stats_med"
printf 'ratio stats/cat: %.2f   (goal >= 0.8)\n' "$ratio"
if [ -n "$compare" ]; then
  compare_med=$(median "${compare_s[@]}")
  printf '%s: %s s, ratio to cat %.2f\n' "$compare" "$compare_med" \
    "$(awk -v c="$cat_med" -v s="$compare_med" 'BEGIN {print c / s}')"
fi
printf 'max |error| of min/max/mean vs generator: %s\n' "$error"
printf 'load average (1, 5, 15 min): %s before, %s after\n' "$load_before" "$(loadavg)"
