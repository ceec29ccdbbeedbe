// libFuzzer harness over the JSON a client or an acquisition folder hands the dataset layer: the
// body of POST /api/datasets and the sidecar of a watched folder (protocol::ParseStreamRequest,
// both kinds), a stream record read back from the state folder (ParseStreamRecord), and the JSON
// an administrator hands the server: the `serve --config` file and the users file
// (protocol::ParseServeConfig, ParseUsersFile). Nothing may crash, hang or allocate
// unboundedly: errors are fine. A parsed request must respect the documented limits.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "protocol/dataset_json.h"
#include "protocol/serve_config.h"

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
  if (auto record = ParseStreamRecord(text, "fuzz-input"); record.ok()) {
    if (record->id.size() != 12 || record->cache.empty() ||
        (record->missing_planes.has_value() && !record->finished) ||
        record->warnings.size() > kMaxStreamRecordWarnings) {
      std::abort();
    }
  }
  if (auto config = ParseServeConfig(text, "fuzz-input"); config.ok()) {
    if (config->max_sessions && (*config->max_sessions < 1 || *config->max_sessions > 100000)) {
      std::abort();
    }
    if (config->users && config->users->size() > kMaxUsers) std::abort();
  }
  if (auto users = ParseUsersFile(text, "fuzz-input"); users.ok()) {
    for (const UserConfig& u : *users) {
      if (u.name.empty() || u.token.has_value() == u.token_file.has_value()) std::abort();
    }
  }
  return 0;
}
