// libFuzzer harness over the Zarr / OME-NGFF JSON parser (protocol/zarr_json.h): input format in
// zarr_fuzz_inputs.h. Nothing may crash, hang, leak or return an internal error.
#include <cstdlib>

#include "zarr_fuzz_inputs.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const octoscope::Status s = octoscope::fuzz::ZarrMetadataInput({data, size});
  if (s.code() == octoscope::StatusCode::kInternal) std::abort();
  return 0;
}
