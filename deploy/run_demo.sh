#!/usr/bin/env bash
# One command from a fresh Debian 12 machine: install what is needed, build, write the built-in
# demo specimen (a synthetic 3-channel fluorescent embryo, OME-TIFF), read it back slab by slab
# (metadata and per-channel statistics) and build its multi-resolution octree cache.
# Usage: bash deploy/run_demo.sh [--size X,Y,Z]   (default 256,256,128)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/deploy/install_deps.sh"
bash "$root/deploy/build.sh"
build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
demo_dir="${OCTOSCOPE_DEMO_DIR:-$root/out/demo}"
demo=$("$build/octoscope" demo --out "$demo_dir" "$@")
echo "demo specimen: $demo"
"$build/octoscope" info --stats "$demo"
"$build/octoscope" build "$demo" --cache "$demo_dir/cache"
