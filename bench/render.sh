#!/usr/bin/env bash
# Benchmark: speed against error of the OpenCL renderer (`octoscope bench render`), with the
# headline ratios against two baselines measured in the same run on the same view: the plain
# dense OpenCL kernel (the volume as one device array, bench/baseline/dense_kernel.h) and the
# hand-written multi-threaded C++ loop (bench/baseline/cpu_raycaster.h).
# Builds (Release) when the binary is missing, writes the demo specimen in memory (no file), runs
# the sweep and leaves docs-ready output in $OCTOSCOPE_BENCH_DIR (default out/bench-render):
#   render_bench.md   the headlines and the table (also printed)
#   render_bench.svg  speed vs error (x: ms per frame, log; y: PSNR against the CPU reference)
#   render_bench.json the same as JSON
#   machine.txt       what it ran on (CPU, cores, load, OpenCL device)
#
# Usage: bash bench/render.sh [DEMO_SIZE] [extra `bench render` flags...]
#   DEMO_SIZE 512 (default) is the issue's case; 128 or 256 for a shorter run.
#   e.g. bash bench/render.sh 256 --sizes 128,256 --reference-size 128
#   sparse: bash bench/render.sh 512 --sizes 256 --headline-only --embryo-percent 30 --threshold 0.05
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
bin="$build/octoscope"
size="${1:-512}"
shift || true
out="${OCTOSCOPE_BENCH_DIR:-$root/out/bench-render}"
mkdir -p "$out"
[ -x "$bin" ] || bash "$root/deploy/build.sh" >/dev/null

{
  echo "date: $(date -Iseconds)"
  echo "cpu: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //'), $(nproc) cores"
  echo "memory: $(awk '/MemTotal/ {printf "%.1f GiB", $2 / 1048576}' /proc/meminfo)"
  echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
  echo "command: octoscope bench render --demo $size --out-dir $out $*"
} > "$out/machine.txt"

start=$(date +%s)
"$bin" bench render --demo "$size" --out-dir "$out" --json "$@" > "$out/render_bench.json"
end=$(date +%s)
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg); wall $((end - start)) s" >> "$out/machine.txt"
cat "$out/machine.txt"
echo
cat "$out/render_bench.md"
