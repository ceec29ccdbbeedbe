#!/usr/bin/env bash
# The wire layers of `octoscope serve` (bench/ws_bench.cpp): strict client-message parsing against
# a plain JSON parse of the same text, and 256 KiB frames through net::Server + a Beast WebSocket
# client against a plain TCP socket over loopback, each ratio measured in the same run.
# Usage: bash bench/ws.sh [FRAMES=400]   (after a Release build into build/)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cmake --build "$root/build" --target ws_bench -j2 >/dev/null
"$root/build/bench/ws_bench" "${1:-400}"
