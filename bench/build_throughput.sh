#!/usr/bin/env bash
# Benchmark: octree construction (`octoscope build`) as ratios measured in one run:
#   construction MB/s / the MB/s of `cp INPUT copy && sync` (reading the input and writing it once
#   is the floor any construction pays), brick pool size / input size, peak RSS / RAM budget;
# for a sparse 1-channel and a dense 3-channel uncompressed OME-TIFF, each with a RAM budget above
# the data size and with --ram-mb 512.
#
# Usage: bash bench/build_throughput.sh [SCALE]
#   SCALE 1 (default): sparse 1536x1536x448 x1 (2.1 GB), dense 1024x1024x512 x3 (3.2 GB).
#   SCALE 0.25 etc. shrinks z for a quick run.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
scale="${1:-1}"

field() { python3 -c "import json,sys; print(json.loads(sys.argv[1])[sys.argv[2]])" "$1" "$2"; }

run_case() {
  local name="$1" size="$2" channels="$3" percent="$4"
  local file="$work/$name.ome.tif"
  if [ "$(cat "$work/$name.params" 2>/dev/null)" != "$size $channels $percent" ] || [ ! -f "$file" ]; then
    echo "writing $name ($size x $channels, embryo $percent%) ..." >&2
    "$bin" demo --out "$work" --name "$name" --size "$size" --channels "$channels" \
      --embryo-percent "$percent" --compression none >/dev/null
    echo "$size $channels $percent" > "$work/$name.params"
  fi
  local bytes; bytes=$(stat -c %s "$file")
  cat "$file" > /dev/null  # Same page-cache state for cp and the builds.
  rm -f "$work/copy.tmp"; sync
  local t0 t1; t0=$(now); cp "$file" "$work/copy.tmp" && sync; t1=$(now)
  rm -f "$work/copy.tmp"
  local cp_mbs; cp_mbs=$(awk -v b="$bytes" -v a="$t0" -v c="$t1" 'BEGIN {print b / (c - a) / 1e6}')
  local big_mb=$(( bytes / 1048576 + 1024 ))
  for ram in "$big_mb" 512; do
    rm -rf "$work/$name.cache"
    local json; json=$("$bin" build "$file" --cache "$work/$name.cache" --ram-mb "$ram" | tail -1)
    local mbs pool_ratio rss; mbs=$(field "$json" mb_per_s); pool_ratio=$(field "$json" pool_ratio)
    rss=$(field "$json" peak_rss_mb)
    printf '| %s | %s x%s | %s | %.0f | %.0f | %.2f | %.2f | %.0f | %.2f | %s |\n' \
      "$name" "$size" "$channels" "$ram" "$cp_mbs" "$mbs" \
      "$(awk -v a="$mbs" -v b="$cp_mbs" 'BEGIN {print a / b}')" "$pool_ratio" "$rss" \
      "$(awk -v a="$rss" -v b="$ram" 'BEGIN {print a / b}')" \
      "$(field "$json" homogeneous_nodes)/$(field "$json" nodes)"
  done
  rm -rf "$work/$name.cache"
}

z_sparse=$(awk -v s="$scale" 'BEGIN {z = int(448 * s); if (z < 8) z = 8; print z}')
z_dense=$(awk -v s="$scale" 'BEGIN {z = int(512 * s); if (z < 8) z = 8; print z}')
echo "| case | size | --ram-mb | cp MB/s | build MB/s | build/cp | pool/input | peak RSS MB | RSS/budget | homogeneous/nodes |"
echo "|---|---|---|---|---|---|---|---|---|---|"
run_case sparse-1ch "1536,1536,$z_sparse" 1 35
run_case dense-3ch "1024,1024,$z_dense" 3 92
