// End-to-end tests of `octoscope build`: statistics, reuse of a complete cache, and crash safety
// (a build SIGKILLed at any point leaves a cache that is detected as incomplete and rebuilt).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <nlohmann/json.hpp>
#include <thread>

#include "app/run_octoscope.h"
#include "io/tiff_fixture.h"

namespace octoscope::app {
namespace {

class BuildCommandTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::MakeTempDir("build");
    input_ = dir_ / "demo-embryo.ome.tif";
    ASSERT_EQ(RunOctoscope("demo --out " + Quote(dir_) +
                           " --size 70,52,40 --channels 2"
                           " --compression deflate")
                  .exit_code,
              0);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Runs a build into `cache` (optionally killing itself after `kill_after` planes).
  RunResult Build(const fs::path& cache, const std::string& extra = "", int kill_after = -1) {
    std::string env = kill_after >= 0
                          ? "OCTOSCOPE_TEST_KILL_AFTER_PLANES=" + std::to_string(kill_after) + " "
                          : "";
    return RunOctoscope(
        "build " + Quote(input_) + " --cache " + Quote(cache) + " --brick 16 --ram-mb 64 " + extra,
        env);
  }

  static nlohmann::json Parse(const RunResult& r) { return nlohmann::json::parse(r.out); }
  static void ExpectSameTree(const nlohmann::json& a, const nlohmann::json& b) {
    for (const char* key : {"nodes", "bricks", "homogeneous_nodes", "pool_bytes", "levels"}) {
      EXPECT_EQ(a[key], b[key]) << key;
    }
  }

  fs::path dir_;
  fs::path input_;
};

TEST_F(BuildCommandTest, BuildsThenReusesWithoutRebuilding) {
  RunResult first = Build(dir_ / "cache");
  ASSERT_EQ(first.exit_code, 0) << first.err;
  auto j = Parse(first);
  for (const char* key : {"nodes", "bricks", "homogeneous_nodes", "pool_bytes", "input_bytes",
                          "seconds", "mb_per_s", "peak_rss_mb"}) {
    EXPECT_TRUE(j.contains(key)) << key;
  }
  EXPECT_EQ(j["input_bytes"], 70 * 52 * 40 * 2 * 2);
  EXPECT_GT(j["bricks"].get<int>(), 0);
  EXPECT_GT(j["nodes"].get<int>(), j["bricks"].get<int>() - 1);
  EXPECT_EQ(j["reused"], false);
  EXPECT_EQ(j["rebuild_reason"], "new");
  EXPECT_EQ(j["levels"], 4);  // 70 -> 16*2^3 = 128 >= 70: levels 0..3.

  const auto pool = dir_ / "cache" / "octree.pool";
  const auto pool_time = fs::last_write_time(pool);
  RunResult second = Build(dir_ / "cache");
  ASSERT_EQ(second.exit_code, 0) << second.err;
  auto k = Parse(second);
  EXPECT_EQ(k["reused"], true);
  ExpectSameTree(j, k);
  EXPECT_EQ(fs::last_write_time(pool), pool_time) << "a reused cache must not be rewritten";
  EXPECT_FALSE(fs::exists(dir_ / "cache" / "BUILDING"));
}

TEST_F(BuildCommandTest, KilledBuildsAreDetectedAndRebuilt) {
  RunResult clean = Build(dir_ / "clean");
  ASSERT_EQ(clean.exit_code, 0) << clean.err;
  const int planes = 40 * 2;
  // Crash points: before the first insert, in the middle, after the last insert (before commit).
  for (int kill_after : {0, 1, planes / 2, planes - 1, planes + 1}) {
    SCOPED_TRACE("killed after " + std::to_string(kill_after) + " planes");
    const fs::path cache = dir_ / ("killed-" + std::to_string(kill_after));
    RunResult killed = Build(cache, "", kill_after);
    EXPECT_NE(killed.exit_code, 0);
    EXPECT_FALSE(fs::exists(cache / "MANIFEST")) << "an interrupted build must not look complete";
    RunResult resumed = Build(cache);
    ASSERT_EQ(resumed.exit_code, 0) << resumed.err;
    auto j = Parse(resumed);
    EXPECT_EQ(j["reused"], false);
    EXPECT_EQ(j["rebuild_reason"], "incomplete (a build was interrupted)");
    ExpectSameTree(j, Parse(clean));
    EXPECT_EQ(Parse(Build(cache))["reused"], true);
  }
}

TEST_F(BuildCommandTest, AsynchronousSigkillNeverLeavesACompleteLookingCache) {
  // Kill a real build from outside at several moments; whatever state it leaves, the next build
  // must end with the same tree as a clean one.
  RunResult clean = Build(dir_ / "clean");
  ASSERT_EQ(clean.exit_code, 0) << clean.err;
  for (int delay_ms : {5, 40, 120}) {
    const fs::path cache = dir_ / ("async-" + std::to_string(delay_ms));
    pid_t pid = fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      // The child's output is not the test's.
      int null_fd = open("/dev/null", O_WRONLY);
      dup2(null_fd, 1);
      dup2(null_fd, 2);
      const std::string in = input_.string(), out = cache.string();
      execl(OCTOSCOPE_BINARY, "octoscope", "build", in.c_str(), "--cache", out.c_str(), "--brick",
            "16", "--ram-mb", "64", static_cast<char*>(nullptr));
      _exit(127);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms));
    kill(pid, SIGKILL);
    int status = 0;
    waitpid(pid, &status, 0);
    RunResult after = Build(cache);
    ASSERT_EQ(after.exit_code, 0) << after.err;
    ExpectSameTree(Parse(after), Parse(clean));
  }
}

TEST_F(BuildCommandTest, ChangedSourceParametersOrManifestRebuild) {
  ASSERT_EQ(Build(dir_ / "cache").exit_code, 0);
  EXPECT_EQ(Parse(Build(dir_ / "cache", "--threshold 0.05"))["rebuild_reason"], "parameters changed");
  { std::ofstream(dir_ / "cache" / "MANIFEST", std::ios::app) << "bogus line\n"; }
  auto j = Parse(Build(dir_ / "cache", "--threshold 0"));
  EXPECT_EQ(j["reused"], false);
  EXPECT_NE(j["rebuild_reason"].get<std::string>().find("unreadable manifest"), std::string::npos);
  // A different scan under the same name.
  ASSERT_EQ(RunOctoscope("demo --out " + Quote(dir_) + " --size 70,52,40 --channels 2 --seed 9")
                .exit_code,
            0);
  EXPECT_EQ(Parse(Build(dir_ / "cache", "--threshold 0.05"))["rebuild_reason"], "source changed");
}

TEST_F(BuildCommandTest, VolumeFourTimesTheBudgetStaysWithinBudgetPlusOverhead) {
  // 256 x 256 x 256 x 2 channels x 2 bytes = 64 MiB of voxels (and an 84 MiB pool) under a 16 MiB
  // budget: out of core for real. docs/cli.md promises peak RSS <= budget + 24 MiB + node table.
  ASSERT_EQ(RunOctoscope("demo --out " + Quote(dir_) +
                         " --name big --size 256,256,256"
                         " --channels 2 --compression none")
                .exit_code,
            0);
  RunResult r = RunOctoscope("build " + Quote(dir_ / "big.ome.tif") + " --cache " +
                             Quote(dir_ / "big-cache") + " --brick 32 --ram-mb 16");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto j = Parse(r);
  EXPECT_EQ(j["input_bytes"], 64 << 20);
  const double node_table_mb = j["nodes"].get<double>() * (12 + 16 * 2) / (1 << 20);
  EXPECT_LE(j["peak_rss_mb"].get<double>(), 16 + 24 + node_table_mb);
  EXPECT_GT(j["pool_bytes"].get<double>(), 4.0 * (16 << 20));
  // And it is the same octree as one built with plenty of RAM.
  RunResult roomy = RunOctoscope("build " + Quote(dir_ / "big.ome.tif") + " --cache " +
                                 Quote(dir_ / "roomy-cache") + " --brick 32 --ram-mb 512");
  ASSERT_EQ(roomy.exit_code, 0) << roomy.err;
  ExpectSameTree(j, Parse(roomy));
}

TEST_F(BuildCommandTest, BudgetTooSmallForTheBricksIsAClearError) {
  RunResult r = RunOctoscope("build " + Quote(input_) + " --cache " + Quote(dir_ / "c") +
                             " --brick 128 --ram-mb 16");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--ram-mb"), std::string::npos) << r.err;
}

TEST_F(BuildCommandTest, BadInputAndUsage) {
  RunResult missing =
      RunOctoscope("build " + Quote(dir_ / "nope.tif") + " --cache " + Quote(dir_ / "c"));
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_NE(missing.err.find("nope.tif"), std::string::npos);
  EXPECT_EQ(RunOctoscope("build " + Quote(input_)).exit_code, 64);  // --cache missing.
  EXPECT_EQ(Build(dir_ / "c", "--brick 15").exit_code, 64);         // Odd brick.
  EXPECT_EQ(Build(dir_ / "c", "--threshold 2").exit_code, 64);
  EXPECT_EQ(Build(dir_ / "c", "--ram-mb 8").exit_code, 64);
}

}  // namespace
}  // namespace octoscope::app
