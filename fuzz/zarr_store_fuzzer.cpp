// libFuzzer harness over a whole OME-Zarr store: the input becomes an image group, its array's
// metadata and chunk files in a scratch folder (format in zarr_fuzz_inputs.h), which OpenVolume
// opens (metadata checks, axes, levels, sharding) and reads completely, in whole and in one-plane
// slabs.
#include <unistd.h>

#include <cstdlib>
#include <filesystem>

#include "zarr_fuzz_inputs.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // /dev/shm keeps the many small files off the disk.
  static const std::filesystem::path scratch =
      std::filesystem::path(std::filesystem::is_directory("/dev/shm") ? "/dev/shm" : "/tmp") /
      ("octoscope-zarr-fuzz-" + std::to_string(getpid()));
  const octoscope::Status s = octoscope::fuzz::ZarrStoreInput({data, size}, scratch);
  if (s.code() == octoscope::StatusCode::kInternal) std::abort();
  return 0;
}
