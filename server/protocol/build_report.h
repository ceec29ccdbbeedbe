// BuildReport: the JSON line `octoscope build` prints when it ends (fields in docs/cli.md).
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_BUILD_REPORT_H_
#define OCTOSCOPE_PROTOCOL_BUILD_REPORT_H_

#include <cstdint>
#include <string>
#include <vector>

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
  double threshold = 0;  // Homogeneity threshold (0 = lossless).
  // Per channel, the largest |voxel - shown value| pruning introduced, in the file's own units
  // (Octree::PruningError through the channel's value map); all 0 when lossless.
  std::vector<double> pruning_error;
  std::vector<int64_t> brick_size;  // The brick size the cache uses (x, y, z).
  // Brick pages read back from the pool file (pages never written are not read: any read is the
  // working set not fitting the budget).
  double pages_reread_mb = 0;
  double pages_written_mb = 0;  // Brick pages written to the pool file (write-backs).
};

std::string BuildReportJson(const BuildReport& report);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_BUILD_REPORT_H_
