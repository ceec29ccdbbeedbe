#include "protocol/render_bench_report.h"

#include <nlohmann/json.hpp>

namespace octoscope::protocol {

std::string RenderBenchReportJson(const RenderBenchReport& r) {
  nlohmann::ordered_json j;
  j["volume"] = r.volume;
  j["device"] = r.device;
  j["reference_size"] = r.reference_size;
  j["reference_step"] = r.reference_step;
  j["seconds"] = r.seconds;
  nlohmann::ordered_json rows = nlohmann::ordered_json::array();
  for (const RenderBenchRow& row : r.rows) {
    nlohmann::ordered_json o;
    o["view"] = row.view;
    o["mode"] = row.mode;
    o["frame_kind"] = row.frame_kind;
    o["size"] = row.size;
    o["lod_bias"] = row.lod_bias;
    o["step"] = row.step;
    o["brick_mb"] = row.brick_mb;
    o["ms"] = row.ms;
    o["fps"] = row.fps;
    o["msamples_per_s"] = row.msamples_per_s;
    o["bricks_uploaded"] = row.bricks_uploaded;
    o["passes"] = row.passes;
    o["psnr_db"] = row.psnr_db;
    o["max_err"] = row.max_err;
    rows.push_back(std::move(o));
  }
  j["rows"] = std::move(rows);
  nlohmann::ordered_json headlines = nlohmann::ordered_json::array();
  for (const RenderBenchHeadline& h : r.headlines) {
    nlohmann::ordered_json o;
    o["name"] = h.name;
    o["value"] = h.value;
    o["goal"] = h.goal;
    o["higher_is_better"] = h.higher_is_better;
    o["note"] = h.note;
    headlines.push_back(std::move(o));
  }
  j["headlines"] = std::move(headlines);
  return j.dump();
}

}  // namespace octoscope::protocol
