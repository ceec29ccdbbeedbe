// Two real processes on one cache directory: while `octoscope build` builds into it (stopped with
// SIGSTOP in the middle, so the test does not race it), a second `build` or `render` neither
// clears it nor builds into it, and says why in one line; the first build then completes.
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

class CacheLockTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::MakeTempDir("cache-lock");
    input_ = dir_ / "demo-embryo.ome.tif";
    // Large enough that its build runs for a while (the test stops it as soon as it starts).
    ASSERT_EQ(RunOctoscope("demo --out " + Quote(dir_) +
                           " --size 256,256,128 --channels 2 --compression none")
                  .exit_code,
              0);
  }
  void TearDown() override {
    if (builder_ > 0) {
      kill(builder_, SIGKILL);
      waitpid(builder_, nullptr, 0);
    }
    fs::remove_all(dir_);
  }

  // Starts `octoscope build INPUT --cache cache` and stops it (SIGSTOP) once it has begun
  // building (its BUILDING mark and its pool exist); returns false if it could not be caught in
  // the act.
  bool StartAndStopBuilder(const fs::path& cache) {
    builder_ = fork();
    if (builder_ < 0) return false;
    if (builder_ == 0) {
      const int null_fd = open("/dev/null", O_WRONLY);
      dup2(null_fd, 1);
      dup2(null_fd, 2);
      const std::string in = input_.string(), out = cache.string();
      execl(OCTOSCOPE_BINARY, "octoscope", "build", in.c_str(), "--cache", out.c_str(), "--brick",
            "16", "--ram-mb", "64", "--threshold", "0", static_cast<char*>(nullptr));
      _exit(127);
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (!fs::exists(cache / "BUILDING") || !fs::exists(cache / "octree.pool")) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      if (waitpid(builder_, nullptr, WNOHANG) == builder_) {  // Ended before building.
        builder_ = -1;
        return false;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    kill(builder_, SIGSTOP);
    int status = 0;
    return waitpid(builder_, &status, WUNTRACED) == builder_ && WIFSTOPPED(status) &&
           fs::exists(cache / "BUILDING");
  }

  // Expects `r` to be refused with one line naming the cache directory and the building process.
  void ExpectRefused(const RunResult& r, const fs::path& cache) {
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    for (const std::string& needle :
         {std::string("unavailable: "), cache.string(),
          std::string("locked by another process that is building into it"),
          "pid " + std::to_string(builder_)}) {
      EXPECT_NE(r.err.find(needle), std::string::npos) << "'" << needle << "' not in: " << r.err;
    }
  }

  fs::path dir_;
  fs::path input_;
  pid_t builder_ = -1;
};

TEST_F(CacheLockTest, ASecondProcessNeitherClearsNorBuildsIntoACacheBeingBuilt) {
  const fs::path cache = dir_ / "cache";
  ASSERT_TRUE(StartAndStopBuilder(cache)) << "the first build could not be caught building";
  const auto pool_size = fs::file_size(cache / "octree.pool");
  const auto pool_time = fs::last_write_time(cache / "octree.pool");

  // A second build of the same scan, of the same scan with other parameters, and renders of the
  // directory (as a cache, and as the cache of the scan).
  ExpectRefused(RunOctoscope("build " + Quote(input_) + " --cache " + Quote(cache) +
                             " --brick 16 --ram-mb 64 --threshold 0"),
                cache);
  ExpectRefused(RunOctoscope("build " + Quote(input_) + " --cache " + Quote(cache) +
                             " --brick 32 --ram-mb 64"),
                cache);
  ExpectRefused(
      RunOctoscope("render " + Quote(cache) + " --out " + Quote(dir_ / "a.png") + " --size 32x32"),
      cache);
  ExpectRefused(RunOctoscope("render " + Quote(input_) + " --cache " + Quote(cache) + " --out " +
                             Quote(dir_ / "b.png") + " --size 32x32"),
                cache);
  EXPECT_FALSE(fs::exists(dir_ / "a.png"));
  EXPECT_FALSE(fs::exists(dir_ / "b.png"));
  // The first build's files are untouched.
  EXPECT_TRUE(fs::exists(cache / "BUILDING"));
  EXPECT_FALSE(fs::exists(cache / "MANIFEST"));
  EXPECT_EQ(fs::file_size(cache / "octree.pool"), pool_size);
  EXPECT_EQ(fs::last_write_time(cache / "octree.pool"), pool_time);

  // The first build carries on and completes; its cache is then reused by the next build.
  kill(builder_, SIGCONT);
  int status = 0;
  ASSERT_EQ(waitpid(builder_, &status, 0), builder_);
  builder_ = -1;
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status;
  EXPECT_TRUE(fs::exists(cache / "MANIFEST"));
  RunResult reuse = RunOctoscope("build " + Quote(input_) + " --cache " + Quote(cache) +
                                 " --brick 16 --ram-mb 64 --threshold 0");
  ASSERT_EQ(reuse.exit_code, 0) << reuse.err;
  EXPECT_EQ(nlohmann::json::parse(reuse.out)["reused"], true);
}

TEST_F(CacheLockTest, AKilledBuilderLeavesNoLockBehind) {
  const fs::path cache = dir_ / "cache";
  ASSERT_TRUE(StartAndStopBuilder(cache)) << "the first build could not be caught building";
  kill(builder_, SIGKILL);
  waitpid(builder_, nullptr, 0);
  builder_ = -1;
  // The kernel released the lock with the process: the next build starts over at once.
  RunResult next = RunOctoscope("build " + Quote(input_) + " --cache " + Quote(cache) +
                                " --brick 16 --ram-mb 64 --threshold 0");
  ASSERT_EQ(next.exit_code, 0) << next.err;
  EXPECT_EQ(nlohmann::json::parse(next.out)["rebuild_reason"],
            "incomplete (a build was interrupted)");
}

}  // namespace
}  // namespace octoscope::app
