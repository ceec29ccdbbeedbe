// libFuzzer harness over the chunk decoders (io/chunk_codecs.h: blosc, zstd, zlib, gzip, LZ4 in
// both framings, CRC32C, unshuffle): input format in zarr_fuzz_inputs.h.
#include <cstdlib>

#include "zarr_fuzz_inputs.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const octoscope::Status s = octoscope::fuzz::ChunkCodecInput({data, size});
  if (s.code() == octoscope::StatusCode::kInternal) std::abort();
  return 0;
}
