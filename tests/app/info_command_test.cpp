// End-to-end tests of `octoscope info`: the real binary on real and generated files.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "app/run_octoscope.h"
#include "io/tiff_fixture.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;

const fs::path kTestdata(OCTOSCOPE_TESTDATA);

TEST(InfoCommandTest, JsonForImageJHyperstack) {
  RunResult r =
      RunOctoscope("info --json " + Quote(kTestdata / "neubias/xyzc_16bit__dna_conf_wf.tif"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["format"], "imagej-tiff");
  EXPECT_EQ(j["size"], nlohmann::json({133, 130, 45}));
  EXPECT_EQ(j["channels"], 2);
  EXPECT_EQ(j["dtype"], "uint16");
  EXPECT_NEAR(j["spacing"][0].get<double>(), 0.512, 1e-3);
  EXPECT_NEAR(j["spacing"][2].get<double>(), 0.499, 1e-3);
  EXPECT_EQ(j["bytes"], 133 * 130 * 45 * 2 * 2);
}

TEST(InfoCommandTest, StatsMatchValuesWrittenByTheTest) {
  fs::path dir = testing::MakeTempDir("info-stats");
  testing::TiffFixtureSpec spec;
  spec.width = 37;
  spec.height = 11;
  spec.pages = 5;
  spec.bits_per_sample = 16;
  spec.sample_format = 2;  // int16: stats are in the file's own (signed) units.
  spec.compression = 8;    // Deflate.
  auto value = [](uint32_t x, uint32_t y, int page, int) {
    return static_cast<double>(static_cast<int>(x * 3 + y * 100 + page * 1000) - 3000);
  };
  ASSERT_TRUE(testing::WriteTiffFixture(dir / "stack.tif", spec, value));
  double lo = 1e9, hi = -1e9, sum = 0;
  for (int p = 0; p < 5; ++p)
    for (uint32_t y = 0; y < 11; ++y)
      for (uint32_t x = 0; x < 37; ++x) {
        double v = value(x, y, p, 0);
        lo = std::min(lo, v);
        hi = std::max(hi, v);
        sum += v;
      }
  RunResult r = RunOctoscope("info --json --stats " + Quote(dir / "stack.tif"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["format"], "tiff");
  EXPECT_EQ(j["dtype"], "int16");
  EXPECT_EQ(j["size"], nlohmann::json({37, 11, 5}));
  EXPECT_EQ(j["min"][0].get<double>(), lo);
  EXPECT_EQ(j["max"][0].get<double>(), hi);
  EXPECT_DOUBLE_EQ(j["mean"][0].get<double>(), sum / (37 * 11 * 5));
  EXPECT_TRUE(r.err.empty()) << "no progress bar when stderr is not a terminal: " << r.err;
  fs::remove_all(dir);
}

TEST(InfoCommandTest, HumanReadableOutputAndSpacingOverride) {
  RunResult r =
      RunOctoscope("info --spacing -,-,7.5 " + Quote(kTestdata / "neubias/xyzc_16bit__spots.tif"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("89 x 88 x 17"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("x 7.5 µm"), std::string::npos) << r.out;
}

TEST(InfoCommandTest, BadInputExitsTwoWithOneLineNamingTheFile) {
  fs::path dir = testing::MakeTempDir("info-bad");
  { std::ofstream(dir / "garbage.tif") << "not a tiff at all"; }
  { std::ofstream(dir / "empty.tif"); }
  for (const char* name : {"garbage.tif", "empty.tif", "missing.tif"}) {
    RunResult r = RunOctoscope("info " + Quote(dir / name));
    EXPECT_EQ(r.exit_code, 2) << name;
    EXPECT_NE(r.err.find(name), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_TRUE(r.out.empty());
  }
  fs::remove_all(dir);
}

TEST(InfoCommandTest, UsageErrorsAndHelp) {
  EXPECT_EQ(RunOctoscope("info").exit_code, 64);
  EXPECT_EQ(RunOctoscope("info a.tif --frobnicate").exit_code, 64);
  EXPECT_EQ(RunOctoscope("info a.tif --series x").exit_code, 64);
  EXPECT_EQ(RunOctoscope("nonsense").exit_code, 64);
  RunResult help = RunOctoscope("info --help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.out.find("--stats"), std::string::npos);
  RunResult top = RunOctoscope("--help");
  EXPECT_EQ(top.exit_code, 0);
  EXPECT_NE(top.out.find("demo"), std::string::npos);
}

TEST(InfoCommandTest, SeriesAndTimeSelection) {
  fs::path mm = kTestdata / "real_ometiff_misc/181003_multi_pos_time_course_1_MMStack.ome.tif";
  RunResult r = RunOctoscope("info --json --series 1 --time 9 " + Quote(mm));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["series"], 1);
  EXPECT_EQ(j["series_count"], 2);
  EXPECT_EQ(j["time"], 9);
  EXPECT_EQ(j["time_points"], 10);
  RunResult bad = RunOctoscope("info --series 2 " + Quote(mm));
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("series"), std::string::npos) << bad.err;
}

}  // namespace
}  // namespace octoscope::app
