// RenderBenchReport: the results of `octoscope bench render` (one row per measured setting plus the
// headline ratios), as the JSON document `bench render --json` prints (fields in docs/cli.md-style
// names: the same as the markdown table's columns).
//
// Thread safety: plain value types; pure functions.
#ifndef OCTOSCOPE_PROTOCOL_RENDER_BENCH_REPORT_H_
#define OCTOSCOPE_PROTOCOL_RENDER_BENCH_REPORT_H_

#include <cstdint>
#include <string>
#include <vector>

namespace octoscope::protocol {

// One measured setting. Invariant: every number is finite (PSNR of identical images is capped).
struct RenderBenchRow {
  std::string view;        // "z", "x", "iso", "persp".
  std::string mode;        // "dvr", "mip".
  std::string frame_kind;  // "cold" (first full frame), "steady" (no more requests), "refined".
  int size = 0;            // Image width = height.
  double lod_bias = 0;
  double step = 1;      // Voxels.
  double brick_mb = 0;  // Brick buffer size.
  double ms = 0;        // Per frame (full frame) or in total (refined).
  double fps = 0;       // 1000 / ms.
  double msamples_per_s = 0;
  uint64_t bricks_uploaded = 0;
  int passes = 0;  // Frames until steady (full frame) or refinement passes.
  double psnr_db = 0;
  double max_err = 0;  // Largest absolute difference of any RGBA component, 0..1.
};

struct RenderBenchHeadline {
  std::string name;  // e.g. "kernel_vs_cpu_msamples_mip".
  double value = 0;
  double goal = 0;  // 0 when the headline has no goal.
  bool higher_is_better = true;
  std::string note;
};

struct RenderBenchReport {
  std::string volume;  // "demo 512^3 x3 uint16" or the input path.
  std::string device;
  int reference_size = 0;
  double reference_step = 0;
  std::vector<RenderBenchRow> rows;
  std::vector<RenderBenchHeadline> headlines;
  double seconds = 0;
};

std::string RenderBenchReportJson(const RenderBenchReport& report);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_RENDER_BENCH_REPORT_H_
