// OctreeCache's directory lock: a cache directory is built by one holder at a time and never
// cleared while another holder uses it; several holders may serve a complete cache at once.
// flock(2) locks belong to open file descriptions, so two OctreeCache objects in one process
// conflict exactly as two processes do (the app tests run two real processes).
#include "octree/octree_cache.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <memory>
#include <string>

#include "volume/value_map.h"

namespace octoscope::octree {
namespace {

namespace fs = std::filesystem;

class OctreeCacheLockTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("octoscope-test-cache-lock-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    params_.info.size = {40, 30, 20};
    params_.info.channels.resize(2);
    params_.info.dtype = volume::DataType::kUint16;
    params_.brick_size = {16, 16, 16};
    params_.threshold = 0;
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Opens the cache for `source` (counting calls of `derive`).
  Result<std::unique_ptr<OctreeCache>> Open(uint64_t source_hash) {
    SourceIdentity source{source_hash, 1000};
    return OctreeCache::Open(
        dir_, source, params_, uint64_t{64} << 20, [this]() -> Result<ValueMapping> {
          ++derived_;
          ValueMapping mapping;
          for (int c = 0; c < 2; ++c) {
            mapping.value_maps.push_back(volume::FixedValueMap(volume::DataType::kUint16));
            mapping.value_range.push_back(65535);
          }
          return mapping;
        });
  }

  // A complete cache of source 1 in dir_, its holder closed.
  void BuildComplete() {
    auto built = Open(1);
    ASSERT_TRUE(built.ok()) << built.status().ToString();
    ASSERT_FALSE((*built)->reused());
    ASSERT_TRUE((*built)->Commit().ok());
  }

  static void ExpectUnavailable(const Status& status, const fs::path& dir, const char* why) {
    EXPECT_EQ(status.code(), StatusCode::kUnavailable) << status.ToString();
    EXPECT_NE(status.message().find(dir.string()), std::string::npos) << status.ToString();
    EXPECT_NE(status.message().find(why), std::string::npos) << status.ToString();
  }

  fs::path dir_;
  CacheParams params_;
  int derived_ = 0;
};

TEST_F(OctreeCacheLockTest, ASecondBuilderIsRefusedAndTouchesNothing) {
  auto first = Open(1);
  ASSERT_TRUE(first.ok()) << first.status().ToString();
  ASSERT_FALSE((*first)->reused());
  ASSERT_TRUE(fs::exists(dir_ / "BUILDING"));
  const auto pool_time = fs::last_write_time(dir_ / "octree.pool");

  // The same source, and another one: both would clear the directory; both are refused before
  // deriving anything.
  for (uint64_t source : {1, 2}) {
    auto second = Open(source);
    ASSERT_FALSE(second.ok());
    ExpectUnavailable(second.status(), dir_, "locked by another process that is building");
    EXPECT_NE(second.status().message().find("pid " + std::to_string(::getpid())),
              std::string::npos)
        << second.status().ToString();
  }
  EXPECT_EQ(derived_, 1);
  EXPECT_TRUE(fs::exists(dir_ / "BUILDING"));
  EXPECT_EQ(fs::last_write_time(dir_ / "octree.pool"), pool_time);

  // The first build completes; once its holder is gone the cache is reused.
  ASSERT_TRUE((*first)->Commit().ok());
  first->reset();
  auto again = Open(1);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_TRUE((*again)->reused());
}

// A committed build only serves the directory: its lock becomes shared, so other holders may
// reuse the cache while the builder still uses it (a server keeps serving what it built), but
// nobody may rebuild it.
TEST_F(OctreeCacheLockTest, ACommittedBuildSharesTheDirectory) {
  auto builder = Open(1);
  ASSERT_TRUE(builder.ok()) << builder.status().ToString();
  ASSERT_FALSE((*builder)->reused());
  ASSERT_TRUE((*builder)->Commit().ok());
  auto reader = Open(1);
  ASSERT_TRUE(reader.ok()) << reader.status().ToString();
  EXPECT_TRUE((*reader)->reused());
  auto rebuild = Open(2);
  ASSERT_FALSE(rebuild.ok());
  ExpectUnavailable(rebuild.status(), dir_, "in use by another process");
  EXPECT_TRUE(fs::exists(dir_ / "MANIFEST"));
}

TEST_F(OctreeCacheLockTest, ReadersShareACompleteCacheAndBlockItsRebuild) {
  BuildComplete();
  const std::string manifest = dir_ / "MANIFEST";
  auto reader = Open(1);
  auto other_reader = Open(1);
  ASSERT_TRUE(reader.ok()) << reader.status().ToString();
  ASSERT_TRUE(other_reader.ok()) << other_reader.status().ToString();
  EXPECT_TRUE((*reader)->reused());
  EXPECT_TRUE((*other_reader)->reused());

  // Another source would rebuild the directory: refused while it is being read, and nothing is
  // removed (the MANIFEST still describes the readers' octree).
  const int derived_before = derived_;
  auto rebuild = Open(2);
  ASSERT_FALSE(rebuild.ok());
  ExpectUnavailable(rebuild.status(), dir_, "in use by another process");
  EXPECT_EQ(derived_, derived_before + 1);  // Derived, then refused before clearing.
  EXPECT_TRUE(fs::exists(manifest));
  EXPECT_FALSE(fs::exists(dir_ / "BUILDING"));

  // With the readers gone the rebuild goes ahead.
  reader->reset();
  other_reader->reset();
  auto rebuilt = Open(2);
  ASSERT_TRUE(rebuilt.ok()) << rebuilt.status().ToString();
  EXPECT_FALSE((*rebuilt)->reused());
  EXPECT_EQ((*rebuilt)->rebuild_reason(), "source changed");
}

TEST_F(OctreeCacheLockTest, CacheLockModes) {
  fs::create_directories(dir_);
  using Mode = CacheLock::Mode;
  {
    auto a = CacheLock::Acquire(dir_, Mode::kExclusive);
    ASSERT_TRUE(a.ok()) << a.status().ToString();
    ExpectUnavailable(CacheLock::Acquire(dir_, Mode::kExclusive).status(), dir_, "in use");
    ExpectUnavailable(CacheLock::Acquire(dir_, Mode::kShared).status(), dir_, "building");
  }
  // Released on destruction; shared locks coexist.
  auto a = CacheLock::Acquire(dir_, Mode::kShared);
  auto b = CacheLock::Acquire(dir_, Mode::kShared);
  ASSERT_TRUE(a.ok() && b.ok());
  ExpectUnavailable(CacheLock::Acquire(dir_, Mode::kExclusive).status(), dir_, "in use");
  // Both want to build: the first to ask loses its lock altogether (flock converts by dropping),
  // so the second gets the directory.
  ExpectUnavailable((*a)->MakeExclusive(), dir_, "in use by another process");
  EXPECT_TRUE((*b)->MakeExclusive().ok());
  EXPECT_EQ((*b)->mode(), Mode::kExclusive);
  ExpectUnavailable(CacheLock::Acquire(dir_, Mode::kShared).status(), dir_, "building");
}

}  // namespace
}  // namespace octoscope::octree
