// End-to-end: a TIFF whose OME-XML is malformed is read as a plain TIFF stack, and every command
// that opens it says so: one warning line on stderr (docs/cli.md, "Warnings"), and for
// `info --json` a "warnings" field; the command still succeeds.
#include <gtest/gtest.h>

#include <algorithm>
#include <nlohmann/json.hpp>
#include <string>

#include "app/run_octoscope.h"
#include "io/tiff_fixture.h"

namespace octoscope::app {
namespace {

class InputWarningTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::MakeTempDir("input-warning");
    input_ = dir_ / "broken.ome.tif";
    testing::TiffFixtureSpec spec;
    spec.width = 24;
    spec.height = 20;
    spec.pages = 6;
    spec.descriptions = {"<?xml version=\"1.0\"?><OME><Image ID=\"Image:0\"><Pixels SizeX=\"24\""};
    ASSERT_TRUE(testing::WriteTiffFixture(input_, spec));
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Expects exactly one warning line on stderr naming the command, the file and what happened.
  void ExpectWarningLine(const RunResult& r, const std::string& command) {
    const std::string prefix = "octoscope " + command + ": warning: " + input_.string();
    const size_t at = r.err.find(prefix);
    ASSERT_NE(at, std::string::npos) << r.err;
    const std::string line = r.err.substr(at, r.err.find('\n', at) - at);
    EXPECT_NE(line.find("OME-XML is malformed"), std::string::npos) << line;
    EXPECT_NE(line.find("read as a plain TIFF instead"), std::string::npos) << line;
    EXPECT_EQ(r.err.find("warning:", at + prefix.size()), std::string::npos)
        << "one warning only: " << r.err;
  }

  fs::path dir_;
  fs::path input_;
};

TEST_F(InputWarningTest, InfoWarnsOnStderrAndInJson) {
  RunResult human = RunOctoscope("info " + Quote(input_));
  ASSERT_EQ(human.exit_code, 0) << human.err;
  ExpectWarningLine(human, "info");
  EXPECT_NE(human.out.find("format      tiff"), std::string::npos) << human.out;

  RunResult json = RunOctoscope("info --json --stats " + Quote(input_));
  ASSERT_EQ(json.exit_code, 0) << json.err;
  ExpectWarningLine(json, "info");
  auto j = nlohmann::json::parse(json.out);
  EXPECT_EQ(j["format"], "tiff");
  EXPECT_EQ(j["size"], nlohmann::json({24, 20, 6}));
  ASSERT_EQ(j["warnings"].size(), 1u);
  EXPECT_NE(j["warnings"][0].get<std::string>().find(input_.string()), std::string::npos);
  EXPECT_NE(j["warnings"][0].get<std::string>().find("malformed"), std::string::npos);

  // A well-formed file has an empty list and no warning line.
  testing::TiffFixtureSpec spec;
  ASSERT_TRUE(testing::WriteTiffFixture(dir_ / "plain.tif", spec));
  RunResult plain = RunOctoscope("info --json " + Quote(dir_ / "plain.tif"));
  ASSERT_EQ(plain.exit_code, 0) << plain.err;
  EXPECT_EQ(plain.err.find("warning"), std::string::npos) << plain.err;
  EXPECT_EQ(nlohmann::json::parse(plain.out)["warnings"], nlohmann::json::array());
}

TEST_F(InputWarningTest, BuildAndRenderWarn) {
  RunResult build = RunOctoscope("build " + Quote(input_) + " --cache " + Quote(dir_ / "cache") +
                                 " --brick 16 --ram-mb 64");
  ASSERT_EQ(build.exit_code, 0) << build.err;
  ExpectWarningLine(build, "build");

  RunResult render = RunOctoscope("render " + Quote(input_) + " --out " + Quote(dir_ / "view.png") +
                                  " --size 24x20 --ram-mb 64");
  ASSERT_EQ(render.exit_code, 0) << render.err;
  ExpectWarningLine(render, "render");
  EXPECT_TRUE(fs::exists(dir_ / "view.png"));
}

}  // namespace
}  // namespace octoscope::app
