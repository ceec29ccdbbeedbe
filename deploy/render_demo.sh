#!/usr/bin/env bash
# One command from a fresh Debian 12 machine: install what is needed, build, write the built-in
# demo specimen (a synthetic 3-channel fluorescent embryo, OME-TIFF), read it back slab by slab
# (metadata and per-channel statistics), build its multi-resolution octree cache and render it
# (OpenCL ray casting: a DVR view and a MIP view, PNG) with the colours of deploy/demo_params.json.
# Usage: bash deploy/render_demo.sh [--size X,Y,Z]   (default 256,256,128)
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
for mode in dvr mip; do
  "$build/octoscope" render "$demo_dir/cache" --out "$demo_dir/demo-$mode.png" --size 512x512 \
    --view iso --mode "$mode" --params "$root/deploy/demo_params.json" --refine --stats-json
done
echo "images: $demo_dir/demo-dvr.png $demo_dir/demo-mip.png"
