#!/usr/bin/env bash
# Bench-only packages for bench/vtk_compare.sh (VTK's ray casters under a virtual X server):
# Debian 12's python3-vtk9, xvfb and xauth (xvfb-run). The build and the test suite never need
# them, so deploy/install_deps.sh does not install them. Idempotent; needs root (or sudo).
set -euo pipefail
packages=(python3-vtk9 python3-numpy xvfb xauth)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
if ((${#missing[@]} == 0)); then
  echo "install_vtk: all ${#packages[@]} packages present"
  exit 0
fi
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
"${sudo_cmd[@]}" apt-get update
DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y --no-install-recommends \
  "${missing[@]}"
