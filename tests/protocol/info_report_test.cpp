#include "protocol/info_report.h"

#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

namespace octoscope::protocol {
namespace {

volume::VolumeInfo SampleInfo() {
  volume::VolumeInfo info;
  info.format = "ome-tiff";
  info.size = {133, 130, 45};
  info.channels = {{"DNA", volume::Rgba{0, 0, 255, 255}}, {"", std::nullopt}};
  info.dtype = volume::DataType::kInt16;
  info.spacing_um = {0.512, 0.512, std::nullopt};
  info.series_count = 3;
  info.series = 1;
  info.time_points = 4;
  info.time = 2;
  return info;
}

TEST(InfoReportTest, MetadataFields) {
  auto j = nlohmann::json::parse(InfoReportJson(SampleInfo(), std::nullopt));
  EXPECT_EQ(j["format"], "ome-tiff");
  EXPECT_EQ(j["size"], nlohmann::json({133, 130, 45}));
  EXPECT_EQ(j["channels"], 2);
  EXPECT_EQ(j["channel_names"], nlohmann::json({"DNA", ""}));
  EXPECT_EQ(j["channel_colors"][0], "#0000ffff");
  EXPECT_TRUE(j["channel_colors"][1].is_null());
  EXPECT_EQ(j["dtype"], "int16");
  EXPECT_EQ(j["stored_dtype"], "uint16");
  EXPECT_DOUBLE_EQ(j["spacing"][0].get<double>(), 0.512);
  EXPECT_TRUE(j["spacing"][2].is_null());
  EXPECT_EQ(j["bytes"], 133u * 130 * 45 * 2 * 2);
  EXPECT_EQ(j["series"], 1);
  EXPECT_EQ(j["series_count"], 3);
  EXPECT_EQ(j["time"], 2);
  EXPECT_EQ(j["time_points"], 4);
  EXPECT_EQ(j["warnings"], nlohmann::json::array());
  EXPECT_FALSE(j.contains("min"));
}

TEST(InfoReportTest, WarningsAreListed) {
  volume::VolumeInfo info = SampleInfo();
  info.warnings = {"a.ome.tif: OME-XML is malformed; read as a plain TIFF instead", "second"};
  auto j = nlohmann::json::parse(InfoReportJson(info, std::nullopt));
  EXPECT_EQ(j["warnings"], nlohmann::json(info.warnings));
}

TEST(InfoReportTest, StatsFieldsWithNullForMissing) {
  io::VolumeStats stats;
  stats.channels.push_back({-5, 300, 12.25, 10, 0});
  stats.channels.push_back({NAN, NAN, NAN, 0, 7});
  auto j = nlohmann::json::parse(InfoReportJson(SampleInfo(), stats));
  EXPECT_EQ(j["min"][0], -5);
  EXPECT_EQ(j["max"][0], 300);
  EXPECT_DOUBLE_EQ(j["mean"][0].get<double>(), 12.25);
  EXPECT_TRUE(j["mean"][1].is_null());
  EXPECT_EQ(j["nan_count"][1], 7);
}

}  // namespace
}  // namespace octoscope::protocol
