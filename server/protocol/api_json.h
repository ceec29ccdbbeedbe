// HTTP API documents (docs/api.md): error bodies, the health document and the query of PUT
// /api/datasets/{id}/slabs. Parsers are strict (unknown fields and parameters refused by name,
// ranges checked) and bounded; they never throw.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_API_JSON_H_
#define OCTOSCOPE_PROTOCOL_API_JSON_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"
#include "volume/data_type.h"

namespace octoscope::protocol {

// Largest JSON request body (the net layer refuses larger ones with 413 before parsing).
inline constexpr size_t kMaxApiJsonBodyBytes = size_t{64} << 10;
inline constexpr int kMaxApiJsonDepth = 8;

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
// dataset are checked here (z + depth within octree::kMaxVolumeAxis, channel below
// octree::kMaxChannels); the dataset checks its own size.
struct SlabQuery {
  int64_t z = 0;
  int64_t depth = 0;
  int channel = 0;
  bool wait = true;
};
Result<SlabQuery> ParseSlabQuery(std::string_view query);

// {"planes_received": N, "planes_inserted": M}
std::string SlabResultJson(int64_t planes_received, int64_t planes_inserted);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_API_JSON_H_
