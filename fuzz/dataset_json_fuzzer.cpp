// libFuzzer harness over the JSON a client or an acquisition folder hands the dataset layer: the
// body of POST /api/datasets and the sidecar of a watched folder (protocol::ParseStreamRequest,
// both kinds). Nothing may crash, hang or allocate unboundedly: errors are fine. A parsed request
// must respect the documented limits.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "protocol/dataset_json.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace octoscope::protocol;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  for (StreamRequestKind kind : {StreamRequestKind::kApi, StreamRequestKind::kSidecar}) {
    auto request = ParseStreamRequest(text, kind, "fuzz-input");
    if (!request.ok()) continue;
    for (int64_t axis : request->size) {
      if (axis < 1 || axis > kMaxStreamAxis) std::abort();
    }
    if (request->channels < 1 || request->channels > kMaxStreamChannels) std::abort();
    if (!request->channel_names.empty() &&
        request->channel_names.size() != static_cast<size_t>(request->channels)) {
      std::abort();
    }
  }
  return 0;
}
