// End-to-end tests of `octoscope demo`: the file it writes reads back through the public readers
// with the generator's own statistics.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "app/run_octoscope.h"
#include "io/tiff_fixture.h"

namespace octoscope::app {
namespace {

TEST(DemoCommandTest, WritesASpecimenThatReadsBackWithTheGeneratorsStatistics) {
  fs::path dir = testing::MakeTempDir("demo");
  RunResult demo = RunOctoscope("demo --out " + Quote(dir / "sub") +
                                " --size 40,30,12 --channels 4 --seed 7 --compression zstd"
                                " --name embryo --stats-json " +
                                Quote(dir / "reference.json"));
  ASSERT_EQ(demo.exit_code, 0) << demo.err;
  EXPECT_EQ(demo.out, (dir / "sub" / "embryo.ome.tif").string() + "\n");
  RunResult info = RunOctoscope("info --json --stats " + Quote(dir / "sub" / "embryo.ome.tif"));
  ASSERT_EQ(info.exit_code, 0) << info.err;
  auto got = nlohmann::json::parse(info.out);
  std::ifstream ref_file(dir / "reference.json");
  auto reference = nlohmann::json::parse(ref_file);
  EXPECT_EQ(got["size"], nlohmann::json({40, 30, 12}));
  EXPECT_EQ(got["channels"], 4);
  EXPECT_EQ(got["channel_names"][0], "nuclei");
  for (const char* key :
       {"size", "channel_names", "channel_colors", "dtype", "spacing", "min", "max", "mean"}) {
    EXPECT_EQ(got[key], reference[key]) << key;
  }
  // Background is dark, nuclei reach far above it.
  EXPECT_LT(got["min"][0].get<double>(), 200);
  EXPECT_GT(got["max"][0].get<double>(), 1000);
  fs::remove_all(dir);
}

TEST(DemoCommandTest, SameSeedSameBytes) {
  fs::path dir = testing::MakeTempDir("demo-seed");
  for (const char* name : {"a", "b"}) {
    ASSERT_EQ(RunOctoscope("demo --out " + Quote(dir) +
                           " --size 16,16,4 --compression none --name " + name)
                  .exit_code,
              0);
  }
  std::ifstream a(dir / "a.ome.tif", std::ios::binary), b(dir / "b.ome.tif", std::ios::binary);
  std::string bytes_a((std::istreambuf_iterator<char>(a)), {});
  std::string bytes_b((std::istreambuf_iterator<char>(b)), {});
  ASSERT_GT(bytes_a.size(), 16u * 16 * 4 * 3 * 2);
  // Files differ only in the image name and UUID inside the OME-XML; compare pixel statistics.
  RunResult ia = RunOctoscope("info --json --stats " + Quote(dir / "a.ome.tif"));
  RunResult ib = RunOctoscope("info --json --stats " + Quote(dir / "b.ome.tif"));
  ASSERT_EQ(ia.exit_code, 0);
  EXPECT_EQ(nlohmann::json::parse(ia.out)["mean"], nlohmann::json::parse(ib.out)["mean"]);
  fs::remove_all(dir);
}

TEST(DemoCommandTest, BadArgumentsAreUsageErrors) {
  EXPECT_EQ(RunOctoscope("demo").exit_code, 64);  // --out missing.
  EXPECT_EQ(RunOctoscope("demo --out /tmp/x --size 10,10").exit_code, 64);
  EXPECT_EQ(RunOctoscope("demo --out /tmp/x --channels 9").exit_code, 64);
  EXPECT_EQ(RunOctoscope("demo --out /tmp/x --compression jpeg2000").exit_code, 64);
  EXPECT_EQ(RunOctoscope("demo --out /tmp/x --name ../escape").exit_code, 64);
  RunResult r = RunOctoscope("demo --out /proc/forbidden --size 2,2,2");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("/proc/forbidden"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace octoscope::app
