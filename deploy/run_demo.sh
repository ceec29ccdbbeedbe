#!/usr/bin/env bash
# One command from a fresh Debian 12 machine: install what is needed, build, and start the viewer
# server on the built-in demo specimen (a synthetic 3-channel fluorescent embryo, written once
# into the cache and streamed in plane by plane like an acquisition). Prints the URL to open in a
# browser (the access token included); Ctrl-C stops the server.
# Usage: bash deploy/run_demo.sh [octoscope serve options, e.g. --port 0 --demo-rate 20]
#   OCTOSCOPE_CACHE_DIR: the cache folder (default out/serve-cache in the checkout).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/deploy/install_deps.sh"
bash "$root/deploy/build.sh"
build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
cache="${OCTOSCOPE_CACHE_DIR:-$root/out/serve-cache}"
mkdir -p "$cache"
echo "starting octoscope serve --demo (open the URL below in a browser; Ctrl-C stops it)" >&2
exec "$build/octoscope" serve --demo --cache "$cache" --web "$root/web" "$@"
