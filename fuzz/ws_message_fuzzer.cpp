// libFuzzer harness over what a WebSocket client (and an uploading acquisition) sends the server:
// the client message parser, the state document, the slab query and the frame header decoder
// (protocol/). Input format in ws_fuzz_input.h. Nothing may crash, hang, leak or return an
// internal error (a broken range invariant).
#include <cstdlib>

#include "ws_fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const octoscope::Status s = octoscope::fuzz::WsMessageInput({data, size});
  if (s.code() == octoscope::StatusCode::kInternal) std::abort();
  return 0;
}
