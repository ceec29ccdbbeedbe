#!/usr/bin/env bash
# Configures and builds Octoscope in Release into build/ (or $OCTOSCOPE_BUILD_DIR).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
jobs="${OCTOSCOPE_JOBS:-$(nproc)}"
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release "$@"
cmake --build "$build" -j "$jobs"
