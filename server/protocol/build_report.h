// BuildReport: the JSON line `octoscope build` prints when it ends (fields in docs/cli.md).
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_BUILD_REPORT_H_
#define OCTOSCOPE_PROTOCOL_BUILD_REPORT_H_

#include <cstdint>
#include <string>

#include "octree/octree.h"

namespace octoscope::protocol {

struct BuildReport {
  octree::OctreeStats stats;
  uint64_t input_bytes = 0;    // Voxel bytes of the source (selected series/time, all channels).
  double seconds = 0;          // Wall time of the whole command.
  double mb_per_s = 0;         // input_bytes / seconds / 1e6.
  double peak_rss_mb = 0;      // Peak resident set of the process.
  double ram_budget_mb = 0;    // --ram-mb.
  bool reused = false;         // An existing complete cache served the request.
  std::string rebuild_reason;  // Why it was built ("" when reused).
  int levels = 0;
  std::string cache_dir;
};

std::string BuildReportJson(const BuildReport& report);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_BUILD_REPORT_H_
