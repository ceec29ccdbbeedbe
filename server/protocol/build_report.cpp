#include "protocol/build_report.h"

#include <algorithm>
#include <nlohmann/json.hpp>

namespace octoscope::protocol {

std::string BuildReportJson(const BuildReport& r) {
  nlohmann::ordered_json j;
  j["nodes"] = r.stats.nodes;
  j["bricks"] = r.stats.bricks;
  j["homogeneous_nodes"] = r.stats.homogeneous_nodes;
  j["pool_bytes"] = r.stats.pool_bytes;
  j["input_bytes"] = r.input_bytes;
  j["pool_ratio"] = r.input_bytes ? static_cast<double>(r.stats.pool_bytes) / r.input_bytes : 0.0;
  j["levels"] = r.levels;
  j["brick"] = r.brick_size;
  j["threshold"] = r.threshold;
  j["lossless"] =
      std::all_of(r.pruning_error.begin(), r.pruning_error.end(), [](double e) { return e == 0; });
  j["pruning_error"] = r.pruning_error;
  j["pages_reread_mb"] = r.pages_reread_mb;
  j["pages_written_mb"] = r.pages_written_mb;
  j["seconds"] = r.seconds;
  j["mb_per_s"] = r.mb_per_s;
  j["peak_rss_mb"] = r.peak_rss_mb;
  j["ram_budget_mb"] = r.ram_budget_mb;
  j["reused"] = r.reused;
  j["rebuild_reason"] = r.rebuild_reason;
  j["cache"] = r.cache_dir;
  return j.dump();
}

}  // namespace octoscope::protocol
