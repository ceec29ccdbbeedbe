// RenderReport: the JSON line `octoscope render --stats-json` prints when it ends (fields in
// docs/cli.md).
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_RENDER_REPORT_H_
#define OCTOSCOPE_PROTOCOL_RENDER_REPORT_H_

#include <cstdint>
#include <string>

namespace octoscope::protocol {

struct RenderReport {
  double ms_total = 0;   // Wall time of the frames / refinement passes (not loading).
  double ms_kernel = 0;  // Of which: ray-casting kernels.
  double ms_upload = 0;  // Of which: brick uploads.
  double ms_load = 0;    // Opening (or building) the octree and the device set-up.
  int passes = 0;        // Kernel passes (full frames, or refinement passes).
  uint64_t bricks_uploaded = 0;
  uint64_t samples = 0;          // Channel samples taken, all passes.
  uint64_t requests = 0;         // Node requests read back, all passes.
  double finished_fraction = 0;  // Rays finished after the last pass.
  bool final = false;            // The image is complete at the level of detail the screen needs.
  bool refine = false;           // --refine.
  int width = 0;
  int height = 0;
  std::string mode;        // "dvr", "mip", "minip".
  std::string projection;  // "ortho", "perspective".
  std::string device;      // DeviceInfo::ToString().
  std::string octree;      // "memory", "cache" (reused), "built-cache".
  std::string out;         // Output file.
};

std::string RenderReportJson(const RenderReport& report);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_RENDER_REPORT_H_
