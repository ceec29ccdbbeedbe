// RenderReport: the JSON line `octoscope render --stats-json` prints when it ends (fields in
// docs/cli.md): the same keys for 3-D views and slice views, plus the slice's own keys.
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
  uint64_t bricks_preloaded = 0;  // The coarsest levels, uploaded before the first frame.
  double scale = 1;               // --scale: rays cast at scale x the size per axis, upsampled.
  double ms_upsample = 0;         // With scale < 1: wall time of that upsampling (not in ms_total).
  uint64_t samples = 0;           // Channel samples taken, all passes.
  uint64_t samples_skipped = 0;   // Channel samples jumped over by empty-space skipping.
  uint64_t requests = 0;          // Node requests read back, all passes.
  double finished_fraction = 0;   // Rays finished after the last pass.
  bool final = false;             // The image is complete at the level of detail the screen needs.
  bool refine = false;            // --refine.
  // Full frames only (printed when ms_last_frame > 0): wall time and process CPU time (all
  // threads) of the last frame — with `final`, a frame that found everything it needed resident,
  // i.e. what re-rendering the finished view costs.
  double ms_last_frame = 0;
  double cpu_s_last_frame = 0;
  int width = 0;
  int height = 0;
  std::string mode;        // "dvr", "mip", "minip"; "slice" for a slice view.
  std::string projection;  // "ortho", "perspective".
  std::string device;      // DeviceInfo::ToString().
  std::string octree;      // "memory", "cache" (reused), "built-cache".
  std::string out;         // Output file.
  // A slice view (--slice): its axis ("x", "y", "z"; empty for a 3-D view, and then the fields
  // below are not printed), plane position, pixel size and the level of detail sampled.
  std::string slice_axis;
  double slice_position_um = 0;
  double um_per_pixel = 0;
  int level = 0;
  int slice_planes = 0;  // Slice planes drawn into a 3-D view (--slice-planes); printed if > 0.
};

std::string RenderReportJson(const RenderReport& report);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_RENDER_REPORT_H_
