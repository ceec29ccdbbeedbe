#!/usr/bin/env bash
# Benchmark: Octoscope against VTK 9's volume ray casters on the same volume, size and views
# (issue 12, item 6; docs/benchmarks.md "Side by side with VTK").
#   VTK: vtkFixedPointVolumeRayCastMapper (CPU, all cores) and vtkGPUVolumeRayCastMapper (OpenGL;
#        Mesa llvmpipe under Xvfb on a machine without GPU), Debian's python3-vtk9.
#   Octoscope: `octoscope render CACHE --refine` (refined, the final image), the first image
#        after opening the cache: one full frame over the coarse levels (preloaded when the
#        cache is opened), at 1/4, 1/2 and full scale (--scale: upsampled as the browser does),
#        and steady frames (everything resident): lossless, and opt-in lossy settings (--step 2,
#        --scale S) for the comparison at VTK's error.
#   Error: every image against Octoscope's double-precision CPU reference of the same view
#        (`octoscope render SCAN --cpu-reference`), as PSNR and max difference of 8-bit RGB
#        composited over black.
# Requires bench/install_vtk.sh (python3-vtk9, xvfb); not needed by the test suite.
#
# Usage: bash bench/vtk_compare.sh [DEMO_SIZE=512] [IMAGE_SIZE=1024] [FRAMES=3] [SPACING=1,1,1]
# SPACING: µm per voxel along x, y, z for both renderers (the demo file says 0.4,0.4,2; the serve
# demo shows 0.5,0.5,1); each spacing wants its own OCTOSCOPE_BENCH_DIR (camera and references).
# Leaves everything in $OCTOSCOPE_BENCH_DIR (default out/bench-vtk): the inputs, every image,
# results.jsonl (one JSON line per measurement), vtk_compare.md (the tables, also printed) and
# vtk_compare.svg (speed against error of the per-frame figures).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
bin="$build/octoscope"
demo="${1:-512}"
size="${2:-1024}"
frames="${3:-3}"
spacing="${4:-1,1,1}"
out="${OCTOSCOPE_BENCH_DIR:-$root/out/bench-vtk}"
py=/usr/bin/python3  # Debian's, where python3-vtk9 lives.
mkdir -p "$out"
[ -x "$bin" ] || bash "$root/deploy/build.sh" >/dev/null
if ! "$py" -c 'import vtk' 2>/dev/null || ! command -v xvfb-run >/dev/null; then
  echo "vtk_compare: needs python3-vtk9 and xvfb: sudo bash bench/install_vtk.sh" >&2
  exit 2
fi
export PYTHONPATH="$root/bench${PYTHONPATH:+:$PYTHONPATH}"
export PYTHONDONTWRITEBYTECODE=1  # No __pycache__ in the checkout.
ms() { date +%s%N | awk '{printf "%.1f", $1 / 1e6}'; }

# 1. Inputs (not timed): the demo scan (one uint16 channel, uncompressed), its Octoscope cache,
#    the raw voxels VTK reads, the camera and the parameters.
scan="$out/demo${demo}.ome.tif"
[ -f "$scan" ] || "$bin" demo --out "$out" --size "$demo,$demo,$demo" --channels 1 \
  --compression none --name "demo${demo}" >/dev/null
[ -f "$out/cache/MANIFEST" ] || "$bin" build "$scan" --cache "$out/cache" >/dev/null 2>&1
[ -f "$out/volume.raw" ] || "$py" "$root/bench/vtk_prepare.py" --tiff "$scan" --out-dir "$out" \
  --spacing ${spacing//,/ } > "$out/inputs.json"
read -r lo hi < <("$py" -c "import json; w = json.load(open('$out/inputs.json'))['window']; print(*w)")

{
  echo "date: $(date -Iseconds)"
  echo "cpu: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //'), $(nproc) cores"
  echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
  echo "volume: ${demo}^3 uint16, voxels $spacing µm, image ${size}x${size}, window $lo..$hi"
} > "$out/machine.txt"
: > "$out/results.jsonl"
compare() { "$py" "$root/bench/vtk_prepare.py" --compare "$1" "$2"; }

for mode in mip dvr; do
  # The voxel grid at SPACING (default 1 µm; the demo file says 0.4 x 0.4 x 2 µm): VTK gets the
  # same grid, its sample distance the length of Octoscope's step along the view and its opacity
  # unit distance Octoscope's opacity reference (the smallest spacing).
  common=(--view "$out/camera.json" --params "$out/params_$mode.json" --size "${size}x${size}"
    --spacing "$spacing")
  # 2. The reference (not timed; one thread, double precision).
  ref="$out/ref_$mode.png"
  [ -f "$ref" ] || "$bin" render "$scan" --cache "$out/cache" --cpu-reference "${common[@]}" \
    --out "$ref"
  # 3. Octoscope: first images after opening the cache, then refined, then steady frames. A
  #    throwaway render first builds the kernels (PoCL keeps them in its disk cache, so this is
  #    once per machine and build, not per file).
  "$bin" render "$out/cache" "${common[@]}" --size 64x64 --max-passes 1 --out "$out/warm.png"
  "$bin" render "$out/cache" "${common[@]}" --size 64x64 --refine --max-passes 1 --out "$out/warm.png"
  # First images: one full frame over level 2 of 512^3 in 64^3 bricks (1 + 8 bricks, preloaded
  # when the cache is opened), at 1/4 and 1/2 scale (the rays per voxel of that level, upsampled
  # to the size as the browser shows an interactive frame), and at full scale. Time to the first
  # image = the command's ms_load + ms_total (from its start: open the cache and the device,
  # preload, one frame, the image in memory; not writing the PNG, as VTK's excludes its window
  # and screenshot); the whole process (wall, CPU) is recorded too.
  for first in "0.25 1" "0.5 2" "1 3"; do
    read -r scale bias <<< "$first"
    img="$out/octoscope_first_scale${scale}_$mode.png"
    t0=$(ms)
    stats=$(/usr/bin/time -f "%U %S" -o "$out/cpu.txt" "$bin" render "$out/cache" "${common[@]}" \
      --scale "$scale" --lod-bias "$bias" --max-passes 1 --stats-json --out "$img")
    t1=$(ms)
    read -r user sys < "$out/cpu.txt"
    err=$(compare "$img" "$ref")
    first_ms=$("$py" -c "import json, sys; j = json.loads(sys.argv[1]); print(j['ms_load'] + j['ms_total'])" "$stats")
    echo "{\"renderer\":\"octoscope\",\"what\":\"first image, scale $scale, lod bias $bias, 1 full frame\",\"mode\":\"$mode\",\"ms_first_image\":$first_ms,\"ms_process\":$(awk "BEGIN{print $t1 - $t0}"),\"cpu_s_process\":$(awk "BEGIN{print $user + $sys}"),\"stats\":$stats,\"error\":$err}" >> "$out/results.jsonl"
  done
  for ((f = 0; f < frames; ++f)); do
    img="$out/octoscope_refined_$mode.png"
    cpu="$out/cpu.txt"
    stats=$(/usr/bin/time -f "%U %S" -o "$cpu" "$bin" render "$out/cache" "${common[@]}" --refine \
      --stats-json --out "$img")
    read -r user sys < "$cpu"
    err=$(compare "$img" "$ref")
    echo "{\"renderer\":\"octoscope\",\"what\":\"refined\",\"mode\":\"$mode\",\"cpu_s_process\":$(awk "BEGIN{print $user + $sys}"),\"stats\":$stats,\"error\":$err}" >> "$out/results.jsonl"
  done
  # Steady frames: full frames until one finds everything resident; that last frame is the
  # refined image re-rendered (what VTK's per-frame figure measures: the volume already loaded).
  # Then the opt-in, lossy settings, each with its error, for the comparison at VTK's error
  # ("equal or lower error"): samples 2 voxels apart (--step 2), and rays cast at SCALE x the
  # size per axis (--scale, upsampled bilinearly as the browser shows interactive frames; the
  # upsampling's time is added to the frame's) at step 1 and 2. OCTOSCOPE_VTK_SCALES: the scales
  # (default "0.5 0.6 0.7 0.8 0.9"; empty: none).
  settings=("1 1" "1 2")
  for scale in ${OCTOSCOPE_VTK_SCALES-0.5 0.6 0.7 0.8 0.9}; do settings+=("$scale 1" "$scale 2"); done
  for setting in "${settings[@]}"; do
    read -r scale step <<< "$setting"
    what="steady"
    [ "$scale" = 1 ] || what="$what, scale $scale"
    [ "$step" = 1 ] || what="$what, step $step"
    for ((f = 0; f < frames; ++f)); do
      img="$out/octoscope_steady_scale${scale}_step${step}_$mode.png"
      stats=$("$bin" render "$out/cache" "${common[@]}" --scale "$scale" --step "$step" \
        --stats-json --out "$img")
      err=$(compare "$img" "$ref")
      echo "{\"renderer\":\"octoscope\",\"what\":\"$what\",\"mode\":\"$mode\",\"stats\":$stats,\"error\":$err}" >> "$out/results.jsonl"
    done
  done
  # 4. VTK, FRAMES processes per mapper (its frame times scatter from process to process, up to
  #    2x on the same input: the report takes medians over the processes).
  for ((run = 0; run < frames; ++run)); do for mapper in fixed gpu; do
    opacity=$("$py" -c "import json; print(json.load(open('$out/params_$mode.json'))['channels'][0]['opacity_scale'])")
    line=$(xvfb-run -a -s "-screen 0 $((size + 64))x$((size + 64))x24" "$py" \
      "$root/bench/vtk_compare.py" --raw "$out/volume.raw" --dims "$demo" "$demo" "$demo" \
      --camera "$out/camera.json" --mode "$mode" --window "$lo" "$hi" --opacity "$opacity" \
      --size "$size" --mapper "$mapper" --frames "$frames" --reference "$ref" \
      --spacing ${spacing//,/ } \
      --out "$out/vtk_${mapper}_$mode.png" | tail -1)
    echo "{\"renderer\":\"vtk\",\"result\":$line}" >> "$out/results.jsonl"
  done; done
done
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)" >> "$out/machine.txt"
"$py" "$root/bench/vtk_report.py" "$out/results.jsonl" "$out/vtk_compare.svg" > "$out/vtk_compare.md"
cat "$out/machine.txt"
echo
cat "$out/vtk_compare.md"
