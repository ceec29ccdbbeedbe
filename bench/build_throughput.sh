#!/usr/bin/env bash
# Benchmark: octree construction (`octoscope build`, lossless default) as ratios measured in one
# run: construction MB/s / the MB/s of `cp INPUT copy && sync` of the same file (reading the input
# and writing it once is the floor any construction pays), brick pool / input, peak RSS against
# the RAM budget, pool pages read back (0 = the working set fitted by design).
#
# Cases: a sparse 1-channel and a dense 3-channel uncompressed OME-TIFF; each built with a RAM
# budget above the data size and with a quarter of the data, both reading brick-deep slabs and
# reading ONE PLANE at a time (--slab-planes 1: how a live acquisition delivers its data).
#
# Usage: bash bench/build_throughput.sh [SCALE]
#   SCALE 1 (default): sparse 1536x1536x448 x1 (2.1 GB), dense 1024x1024x512 x3 (3.2 GB).
#   SCALE 0.25 etc. shrinks z for a quick run.
# OCTOSCOPE_COMPARE_BIN=/path/to/older/octoscope adds rows for that binary (same flags, without
# --slab-planes), measured in the same run.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
compare="${OCTOSCOPE_COMPARE_BIN:-}"
scale="${1:-1}"

field() { python3 -c "import json,sys; print(json.loads(sys.argv[1]).get(sys.argv[2], '-'))" "$1" "$2"; }

cp_mbs() {
  local file="$1" bytes t0 t1
  bytes=$(stat -c %s "$file")
  cat "$file" > /dev/null  # Same page-cache state for cp and the builds.
  rm -f "$work/copy.tmp"; sync
  t0=$(now); cp "$file" "$work/copy.tmp" && sync; t1=$(now)
  rm -f "$work/copy.tmp"
  awk -v b="$bytes" -v a="$t0" -v c="$t1" 'BEGIN {print b / (c - a) / 1e6}'
}

row() {  # row NAME SIZE CHANNELS BIN LABEL RAM SLAB_PLANES FILE CP_MBS
  local name="$1" size="$2" channels="$3" binary="$4" label="$5" ram="$6" planes="$7" file="$8"
  local cp="$9" extra=() json
  [ "$planes" != "-" ] && extra=(--slab-planes "$planes")
  rm -rf "$work/$name.cache"; sync
  json=$("$binary" build "$file" --cache "$work/$name.cache" --ram-mb "$ram" "${extra[@]}" \
    --threshold 0 2>/dev/null | tail -1)
  local mbs rss; mbs=$(field "$json" mb_per_s); rss=$(field "$json" peak_rss_mb)
  printf '| %s | %s x%s | %s | %s | %s | %.0f | %.0f | **%.2f** | %.2f | %.0f | %+.0f | %s |\n' \
    "$name" "$size" "$channels" "$label" "$ram" "$planes" "$cp" "$mbs" \
    "$(awk -v a="$mbs" -v b="$cp" 'BEGIN {print a / b}')" "$(field "$json" pool_ratio)" "$rss" \
    "$(awk -v a="$rss" -v b="$ram" 'BEGIN {print a - b}')" "$(field "$json" pages_reread_mb)"
  rm -rf "$work/$name.cache"
}

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
  local big_mb=$(( bytes / 1048576 + 1024 )) quarter_mb=$(( bytes / 1048576 / 4 ))
  for ram in "$big_mb" "$quarter_mb"; do
    for planes in - 1; do
      local cp; cp=$(cp_mbs "$file")
      row "$name" "$size" "$channels" "$bin" "this" "$ram" "$planes" "$file" "$cp"
      if [ -n "$compare" ] && [ "$planes" = "-" ]; then
        row "$name" "$size" "$channels" "$compare" "before" "$ram" "$planes" "$file" "$cp"
      fi
    done
  done
}

z_sparse=$(awk -v s="$scale" 'BEGIN {z = int(448 * s); if (z < 8) z = 8; print z}')
z_dense=$(awk -v s="$scale" 'BEGIN {z = int(512 * s); if (z < 8) z = 8; print z}')
echo "load average before: $(loadavg)"
echo "| case | size | binary | --ram-mb | planes/read | cp MB/s | build MB/s | build/cp | pool/input | peak RSS MB | RSS − budget MB | pages re-read MB |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
run_case sparse-1ch "1536,1536,$z_sparse" 1 35
run_case dense-3ch "1024,1024,$z_dense" 3 92
echo "load average after: $(loadavg)"
