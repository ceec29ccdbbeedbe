#!/usr/bin/env bash
# One command from a fresh Debian 12 machine: install what is needed, build, run the whole test
# suite. Tests read third-party files from ../shared/testdata beside the checkout.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/deploy/install_deps.sh"
bash "$root/deploy/build.sh" -DOCTOSCOPE_WERROR=ON
build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
cd "$build"
ctest --output-on-failure --timeout 300 -j "${OCTOSCOPE_JOBS:-$(nproc)}"
