#include "protocol/info_report.h"

#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "volume/value_map.h"

namespace octoscope::protocol {
namespace {

// JSON has no NaN: a statistic that does not exist (an all-NaN channel) is null.
nlohmann::json Number(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); }

std::string HexColor(const volume::Rgba& c) {
  char buf[10];
  std::snprintf(buf, sizeof buf, "#%02x%02x%02x%02x", c.r, c.g, c.b, c.a);
  return buf;
}

}  // namespace

std::string InfoReportJson(const volume::VolumeInfo& info,
                           const std::optional<io::VolumeStats>& stats) {
  nlohmann::ordered_json j;
  j["format"] = info.format;
  j["size"] = {info.size[0], info.size[1], info.size[2]};
  j["channels"] = info.channel_count();
  nlohmann::json names = nlohmann::json::array();
  nlohmann::json colors = nlohmann::json::array();
  nlohmann::ordered_json windows = nlohmann::ordered_json::array();
  for (const volume::ChannelInfo& c : info.channels) {
    names.push_back(c.name);
    colors.push_back(c.color ? nlohmann::json(HexColor(*c.color)) : nlohmann::json());
    if (c.window) {
      nlohmann::ordered_json w;
      w["start"] = c.window->start;
      w["end"] = c.window->end;
      w["min"] = c.window->min ? nlohmann::ordered_json(*c.window->min) : nlohmann::ordered_json();
      w["max"] = c.window->max ? nlohmann::ordered_json(*c.window->max) : nlohmann::ordered_json();
      windows.push_back(std::move(w));
    } else {
      windows.push_back(nlohmann::ordered_json());
    }
  }
  j["channel_names"] = names;
  j["channel_colors"] = colors;
  j["channel_windows"] = windows;
  j["dtype"] = std::string(volume::NumpyName(info.dtype));
  j["stored_dtype"] = std::string(volume::NumpyName(volume::StoredTypeFor(info.dtype)));
  nlohmann::json spacing = nlohmann::json::array();
  for (const auto& s : info.spacing_um)
    spacing.push_back(s ? nlohmann::json(*s) : nlohmann::json());
  j["spacing"] = spacing;
  j["bytes"] = info.VoxelBytes();
  j["series"] = info.series;
  j["series_count"] = info.series_count;
  j["time"] = info.time;
  j["time_points"] = info.time_points;
  j["level"] = info.level;
  j["level_count"] = info.level_count;
  j["warnings"] = info.warnings;
  if (stats) {
    nlohmann::json mins = nlohmann::json::array(), maxs = nlohmann::json::array(),
                   means = nlohmann::json::array(), nans = nlohmann::json::array();
    for (const io::ChannelStats& c : stats->channels) {
      mins.push_back(Number(c.min));
      maxs.push_back(Number(c.max));
      means.push_back(Number(c.mean));
      nans.push_back(c.nan_count);
    }
    j["min"] = mins;
    j["max"] = maxs;
    j["mean"] = means;
    j["nan_count"] = nans;
  }
  return j.dump();
}

}  // namespace octoscope::protocol
