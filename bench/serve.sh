#!/usr/bin/env bash
# Benchmark: what browser users of `octoscope serve` get with 1, 4 and 8 concurrent clients
# dragging the camera of one dataset and of two different ones — answered camera messages per
# second per client, camera → frame latency (p50, p95), KB per frame, frames dropped as stale, and
# the PSNR of the interactive frames against the lossless final frame of the same state.
# The server is the real binary on loopback; the clients are bench/serve_bench.cpp (Beast
# WebSocket), one thread each, each acknowledging every frame as a browser does.
#
# Then fairness (issue 11): 8 clients on the two datasets — 6 dragging as above, and 2 heavy ones
# that are idle for SECONDS and then, for SECONDS more, take 4K screenshots back to back / keep
# refining at 1920x1080 — each interactive client's cameras/s and latency idle vs loaded.
#
# Usage: bash bench/serve.sh [SIZE] [SECONDS] [VIEWPORT] [WHAT]   (default 512 10 512x512 all)
#   SIZE: the demo specimens are SIZE^3 x 3 channels uint16 (two of them, different seeds).
#   WHAT: all, clients (the 1/4/8-client table only) or fairness (the fairness table only).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
size="${1:-512}"
seconds="${2:-10}"
viewport="${3:-512x512}"
what="${4:-all}"
[ -x "$build/bench/serve_bench" ] || cmake --build "$build" --target serve_bench >/dev/null
data="$work/serve-data-$size"
cache="$work/serve-cache"
mkdir -p "$data"
for seed in 1 2; do
  if [ ! -f "$data/specimen$seed.ome.tif" ]; then
    echo "writing specimen $seed ($size^3 x 3) ..." >&2
    "$bin" demo --out "$data" --name "specimen$seed" --size "$size,$size,$size" --channels 3 \
      --seed "$seed" --compression none >/dev/null
  fi
done
token="bench-token-$(date +%s)-0123456789"
"$bin" serve --data "$data" --cache "$cache" --port 0 --token "$token" --ram-mb 8192 \
  > "$work/serve-url.txt" 2> "$work/serve.log" &
server=$!
trap 'kill $server 2>/dev/null; wait $server 2>/dev/null || true' EXIT
for _ in $(seq 600); do [ -s "$work/serve-url.txt" ] && break; sleep 0.1; done
url=$(head -1 "$work/serve-url.txt")
port=$(echo "$url" | sed -E 's|.*:([0-9]+)/.*|\1|')
ids=$(curl -s -H "Authorization: Bearer $token" "http://127.0.0.1:$port/api/datasets" |
  python3 -c 'import json,sys; print(",".join(d["id"] for d in sorted(json.load(sys.stdin), key=lambda d: d["name"])))')
first=${ids%%,*}
echo "load average before: $(loadavg)"
if [ "$what" != fairness ]; then
echo "| clients | datasets | viewport | cameras/s per client (min) | (median) | latency p50 ms | p95 ms | KB/frame | dropped % | PSNR interactive vs final (dB) |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for clients in 1 4 8; do
  "$build/bench/serve_bench" --port "$port" --token "$token" --datasets "$first" \
    --clients "$clients" --seconds "$seconds" --viewport "$viewport"
  if [ "$clients" -gt 1 ]; then
    "$build/bench/serve_bench" --port "$port" --token "$token" --datasets "$ids" \
      --clients "$clients" --seconds "$seconds" --viewport "$viewport"
  fi
done
fi
if [ "$what" != clients ]; then
  echo
  echo "Fairness: 6 interactive clients ($viewport) + 2 heavy clients on 2 datasets, ${seconds} s idle, ${seconds} s loaded"
  "$build/bench/serve_bench" --port "$port" --token "$token" --datasets "$ids" \
    --clients 6 --seconds "$seconds" --viewport "$viewport" --heavy 1
fi
echo "load average after: $(loadavg)"
