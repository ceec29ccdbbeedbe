# seed_dirs HARNESS: prints (one per line) the folders a libFuzzer harness starts from — its
# seeds and its regressions (fuzz/README.md). Sourced by fuzz/run.sh and fuzz/ci_run.sh.
seed_dirs() {
  local fuzz_dir
  fuzz_dir="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
  case "$1" in
    tiff_ome_fuzzer) printf '%s\n' "$fuzz_dir/seeds" "$fuzz_dir/regressions" ;;
    dataset_json_fuzzer) printf '%s\n' "$fuzz_dir/seeds-json" ;;
    ws_message_fuzzer) printf '%s\n' "$fuzz_dir/ws/seeds" "$fuzz_dir/ws/regressions" ;;
    *)
      local name="${1%_fuzzer}"
      mkdir -p "$fuzz_dir/zarr/regressions/$name"
      printf '%s\n' "$fuzz_dir/zarr/seeds/$name" "$fuzz_dir/zarr/regressions/$name"
      ;;
  esac
}
