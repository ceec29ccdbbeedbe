// HTTP API documents (docs/api.md) other than the dataset layer's (protocol/dataset_json.h):
// error bodies, the health document, and the query and answer of PUT /api/datasets/{id}/slabs.
// Parsers are strict (unknown parameters refused by name, ranges checked) and bounded; they
// never throw.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_API_JSON_H_
#define OCTOSCOPE_PROTOCOL_API_JSON_H_

#include <cstddef>
#include <cstdint>
#include <string>
#include <optional>
#include <string_view>
#include <vector>

#include "util/result.h"

namespace octoscope::protocol {

// Largest JSON request body (the net layer refuses larger ones with 413 before reading them).
inline constexpr size_t kMaxApiJsonBodyBytes = size_t{64} << 10;

// {"error": MESSAGE}; the message is made one line of at most 1000 bytes.
std::string HttpErrorJson(std::string_view message);

struct HealthInfo {
  std::string version;
  double uptime_s = 0;
  int64_t datasets = 0;
  int64_t sessions = 0;
};
// {"status":"ok","version":..,"uptime_s":..,"datasets":..,"sessions":..}
std::string HealthJson(const HealthInfo& health);

// The query of PUT /api/datasets/{id}/slabs: z, depth, channel, optional wait (0 or 1, default
// 1); a "token" parameter is ignored (the net layer checked it). Ranges not depending on the
// dataset are checked here (z + depth within kMaxStreamAxis, channel below
// kMaxStreamChannels); the dataset checks its own size.
struct SlabQuery {
  int64_t z = 0;
  int64_t depth = 0;
  int channel = 0;
  bool wait = true;
};
Result<SlabQuery> ParseSlabQuery(std::string_view query);

// {"planes_received": N, "planes_inserted": M}
std::string SlabResultJson(int64_t planes_received, int64_t planes_inserted);

// One entry of GET /api/views (docs/api.md).
struct ViewLinkInfo {
  std::string id;
  std::string url;
  std::string dataset;
  std::string dataset_name;  // "" when the dataset is not known (any more).
  std::string made_through;  // "user", "share" or "view": the kind of grant it was made under.
  std::string owner;         // The owning user's name; "" when the name is no longer a user.
  int64_t created_unix_s = 0;
  std::optional<int64_t> expires_unix_s;
  bool valid = false;   // It opens now.
  std::string reason;   // Why not, when it does not.
};
// [{"id","url","dataset","dataset_name","made_through","owner","created","expires","valid",
//   "reason"}...]; empty names and reasons are null.
std::string ViewLinkListJson(const std::vector<ViewLinkInfo>& links);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_API_JSON_H_
