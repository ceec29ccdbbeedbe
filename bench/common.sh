# Shared set-up of the benchmark scripts (sourced, not run): the checkout root, the build (built
# in Release when the binary is missing), the work folder, and timing helpers.
#   root, build, bin, work: paths; OCTOSCOPE_BUILD_DIR and OCTOSCOPE_BENCH_DIR override.
#   now: seconds since the epoch with nanoseconds. median V...: the median of the numbers.
#   loadavg: the 1, 5 and 15 minute load averages (the machine is shared: say how busy it was).
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
bin="$build/octoscope"
work="${OCTOSCOPE_BENCH_DIR:-$root/out/bench}"
mkdir -p "$work"
[ -x "$bin" ] || bash "$root/deploy/build.sh" >/dev/null
now() { date +%s.%N; }
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
loadavg() { cut -d' ' -f1-3 /proc/loadavg; }
