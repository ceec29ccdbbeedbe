#include "protocol/render_report.h"

#include <nlohmann/json.hpp>

namespace octoscope::protocol {

std::string RenderReportJson(const RenderReport& r) {
  nlohmann::ordered_json j;
  j["ms_total"] = r.ms_total;
  j["passes"] = r.passes;
  j["bricks_uploaded"] = r.bricks_uploaded;
  j["bricks_preloaded"] = r.bricks_preloaded;
  j["samples"] = r.samples;
  j["samples_skipped"] = r.samples_skipped;
  j["final"] = r.final;
  j["width"] = r.width;
  j["height"] = r.height;
  if (r.scale != 1) {
    j["scale"] = r.scale;
    j["ms_upsample"] = r.ms_upsample;
  }
  j["mode"] = r.mode;
  j["device"] = r.device;
  j["projection"] = r.projection;
  j["refine"] = r.refine;
  j["ms_kernel"] = r.ms_kernel;
  j["ms_upload"] = r.ms_upload;
  j["ms_load"] = r.ms_load;
  j["requests"] = r.requests;
  j["finished_fraction"] = r.finished_fraction;
  if (r.ms_last_frame > 0) {
    j["ms_last_frame"] = r.ms_last_frame;
    j["cpu_s_last_frame"] = r.cpu_s_last_frame;
  }
  j["octree"] = r.octree;
  j["out"] = r.out;
  if (!r.slice_axis.empty()) {
    j["slice_axis"] = r.slice_axis;
    j["slice_position_um"] = r.slice_position_um;
    j["um_per_pixel"] = r.um_per_pixel;
    j["level"] = r.level;
  }
  if (r.slice_planes > 0) j["slice_planes"] = r.slice_planes;
  // Device names may hold bytes that are not UTF-8: replace rather than throw.
  return j.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace);
}

}  // namespace octoscope::protocol
