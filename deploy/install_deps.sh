#!/usr/bin/env bash
# Installs every Debian 12 package Octoscope needs to build, test and run.
# Idempotent and non-interactive; needs root (or sudo) and Debian's package registry.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config git python3 curl
  libtiff-dev libzstd-dev liblzma-dev libdeflate-dev zlib1g-dev libjpeg62-turbo-dev
  libpugixml-dev nlohmann-json3-dev
  libblosc-dev liblz4-dev libhdf5-dev
  libboost-dev
  libturbojpeg0-dev
  ocl-icd-opencl-dev opencl-c-headers opencl-clhpp-headers pocl-opencl-icd clinfo
  libgtest-dev googletest
  clang libclang-rt-14-dev
  python3-numpy python3-zarr python3-numcodecs python3-h5py
  nodejs chromium
  # The deploy tests (tests/deploy): nginx and a certificate made with openssl in front of the
  # server, a TLS client (libssl-dev), systemd-analyze. They run nginx as their own process; the
  # packaged nginx service is not needed (`systemctl disable --now nginx` where it is unwanted).
  nginx openssl libssl-dev systemd
)

# Skip apt entirely when everything is already there (fast re-runs, offline machines).
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
# npm: Debian's package, unless the installed Node.js brings its own (e.g. NodeSource's nodejs,
# which conflicts with Debian's npm). The browser tests install playwright-core with it.
if ! command -v npm >/dev/null 2>&1; then missing+=(npm); fi
if ((${#missing[@]} == 0)); then
  echo "install_deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo_cmd=()
if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
export DEBIAN_FRONTEND=noninteractive
echo "install_deps: installing ${missing[*]}"
"${sudo_cmd[@]}" apt-get update -q
"${sudo_cmd[@]}" apt-get install -y -q --no-install-recommends "${missing[@]}"
