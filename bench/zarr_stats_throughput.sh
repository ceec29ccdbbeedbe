#!/usr/bin/env bash
# Benchmark: `octoscope info --stats` throughput on a >= 1 GB blosc-lz4 OME-Zarr, as a ratio
# against `cat` of its chunk files in the same run (both from the page cache: the store is read
# once before timing, so this measures decoding + summing against the cheapest possible reader of
# the same bytes). Also reported: the ratio with one decoding thread (--decode-threads 1), the
# same statistics computed by python3-zarr + numpy (the reference implementation, slab of 64 planes
# at a time), and the error of the statistics against the generator's own (computed from the
# generated voxels).
#
# The store is written by python3-zarr/numcodecs (Debian): 2 channels uint16, C-ordered chunks
# (1, 64, 256, 256), blosc lz4 level 5 with byte shuffle (numcodecs' defaults), NGFF 0.4 metadata.
# Voxels: a smooth specimen-like pattern plus Poisson noise (compresses about 1.8:1).
#
# Usage: bash bench/zarr_stats_throughput.sh [SIZE_X,Y,Z] [CHANNELS] [REPEATS]
#   default 1024,1024,256 x 2 channels uint16 = 1 GiB decoded, 3 repeats (median reported).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
size="${1:-1024,1024,256}"
channels="${2:-2}"
repeats="${3:-3}"
python=/usr/bin/python3
[ -x "$python" ] || python=python3

store="$work/zarr-bench.ome.zarr"
reference="$work/zarr-bench.reference.json"
if [ ! -d "$store" ] || [ ! -f "$reference" ] ||
   [ "$(cat "$work/zarr-bench.params" 2>/dev/null)" != "$size $channels" ]; then
  echo "writing $size x $channels channels blosc-lz4 OME-Zarr ..." >&2
  rm -rf "$store"
  "$python" - "$store" "$reference" "$size" "$channels" <<'PY'
import json, sys
import numcodecs, numpy as np, zarr
store, reference, size, channels = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
X, Y, Z = map(int, size.split(","))
group = zarr.group(store=zarr.DirectoryStore(store), overwrite=True)
arr = group.create_dataset("0", shape=(channels, Z, Y, X), chunks=(1, 64, 256, 256),
                           dtype="<u2", compressor=numcodecs.Blosc(cname="lz4", clevel=5,
                                                                   shuffle=numcodecs.Blosc.SHUFFLE))
group.attrs["multiscales"] = [{"version": "0.4", "axes": [
    {"name": "c", "type": "channel"}] + [{"name": n, "type": "space", "unit": "micrometer"}
                                         for n in "zyx"],
    "datasets": [{"path": "0", "coordinateTransformations": [
        {"type": "scale", "scale": [1, 2.0, 0.5, 0.5]}]}]}]
rng = np.random.default_rng(1)
yy, xx = np.mgrid[0:Y, 0:X].astype(np.float32)
lo, hi, total = [65535] * channels, [0] * channels, [0] * channels
for c in range(channels):
    for z0 in range(0, Z, 64):
        nz = min(64, Z - z0)
        slab = np.empty((nz, Y, X), dtype="<u2")
        for k in range(nz):
            z = z0 + k
            r2 = ((xx - X / 2) / (0.4 * X)) ** 2 + ((yy - Y / 2) / (0.35 * Y)) ** 2 + \
                 ((z - Z / 2) / (0.45 * Z)) ** 2
            signal = np.where(r2 < 1, 3000 * (1 + np.sin(xx * (0.05 + 0.02 * c)) *
                                              np.cos(yy * 0.03 + z * 0.1)), 0)
            noise = rng.poisson(100, size=(Y, X))
            slab[k] = np.clip(signal + noise, 0, 65535).astype("<u2")
        arr[c, z0:z0 + nz] = slab
        lo[c] = min(lo[c], int(slab.min()))
        hi[c] = max(hi[c], int(slab.max()))
        total[c] += int(slab.sum(dtype=np.int64))
voxels = X * Y * Z
json.dump({"min": lo, "max": hi, "mean": [t / voxels for t in total]}, open(reference, "w"))
PY
  echo "$size $channels" > "$work/zarr-bench.params"
fi
decoded=$("$bin" info --json "$store" | "$python" -c 'import json,sys; print(json.load(sys.stdin)["bytes"])')
stored=$(find "$store" -type f ! -name '.z*' -printf '%s\n' | awk '{s += $1} END {print s}')
chunk_list="$work/zarr-bench.chunks"
find "$store" -type f ! -name '.z*' > "$chunk_list"

xargs -a "$chunk_list" cat > /dev/null  # Warm the page cache once.
python_stats() {
  "$python" - "$store" <<'PY'
import sys, numpy as np, zarr
a = zarr.open_group(sys.argv[1], mode="r")["0"]
for c in range(a.shape[0]):
    lo, hi, total = None, None, 0
    for z0 in range(0, a.shape[1], 64):
        s = a[c, z0:z0 + 64]
        lo = s.min() if lo is None else min(lo, s.min())
        hi = s.max() if hi is None else max(hi, s.max())
        total += int(s.sum(dtype=np.int64))
PY
}
cat_s=(); stats_s=(); one_s=(); py_s=()
for _ in $(seq "$repeats"); do
  t0=$(now); xargs -a "$chunk_list" cat > /dev/null; t1=$(now)
  "$bin" info --stats --json "$store" > "$work/zarr-bench.out.json"; t2=$(now)
  "$bin" info --stats --json --decode-threads 1 "$store" > /dev/null; t3=$(now)
  python_stats; t4=$(now)
  cat_s+=("$(awk -v a="$t0" -v b="$t1" 'BEGIN {print b - a}')")
  stats_s+=("$(awk -v a="$t1" -v b="$t2" 'BEGIN {print b - a}')")
  one_s+=("$(awk -v a="$t2" -v b="$t3" 'BEGIN {print b - a}')")
  py_s+=("$(awk -v a="$t3" -v b="$t4" 'BEGIN {print b - a}')")
done
cat_med=$(median "${cat_s[@]}")
stats_med=$(median "${stats_s[@]}")
one_med=$(median "${one_s[@]}")
py_med=$(median "${py_s[@]}")
# Throughput in decoded bytes per second for octoscope; cat moves the stored (compressed) bytes.
cat_mbs=$(awk -v b="$stored" -v s="$cat_med" 'BEGIN {print b / s / 1e6}')
stats_mbs=$(awk -v b="$decoded" -v s="$stats_med" 'BEGIN {print b / s / 1e6}')
one_mbs=$(awk -v b="$decoded" -v s="$one_med" 'BEGIN {print b / s / 1e6}')
py_mbs=$(awk -v b="$decoded" -v s="$py_med" 'BEGIN {print b / s / 1e6}')

error=$("$python" - "$reference" "$work/zarr-bench.out.json" <<'PY'
import json, sys
ref, got = (json.load(open(p)) for p in sys.argv[1:3])
print(max(abs(a - b) for k in ("min", "max", "mean") for a, b in zip(ref[k], got[k])))
PY
)

printf 'store: %s (%d decoded bytes, %d stored bytes, ratio %.2f)\n' "$store" "$decoded" "$stored" \
  "$(awk -v a="$decoded" -v b="$stored" 'BEGIN {print a / b}')"
printf 'cat chunk files:          %8.3f s  %8.1f MB/s stored  (median of %d)\n' "$cat_med" "$cat_mbs" "$repeats"
printf 'info --stats:             %8.3f s  %8.1f MB/s decoded (median of %d)\n' "$stats_med" "$stats_mbs" "$repeats"
printf 'info --stats, 1 decoder:  %8.3f s  %8.1f MB/s decoded (median of %d)\n' "$one_med" "$one_mbs" "$repeats"
printf 'python3-zarr + numpy:     %8.3f s  %8.1f MB/s decoded (median of %d)\n' "$py_med" "$py_mbs" "$repeats"
printf 'time ratio cat/stats: %.2f   (1 decoding thread: %.2f)   python3-zarr/stats: %.2f\n' \
  "$(awk -v a="$cat_med" -v b="$stats_med" 'BEGIN {print a / b}')" \
  "$(awk -v a="$cat_med" -v b="$one_med" 'BEGIN {print a / b}')" \
  "$(awk -v a="$py_med" -v b="$stats_med" 'BEGIN {print a / b}')"
printf 'max |error| of min/max/mean vs generator: %s\n' "$error"
printf 'load average: %s\n' "$(loadavg)"
