#include "io/tiff_file_cache.h"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>
#include <vector>

#include "io/tiff_fixture.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

class TiffFileCacheTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::MakeTempDir("tiff-file-cache");
    for (int i = 0; i < 5; ++i) {
      testing::TiffFixtureSpec spec;
      spec.width = 4 + i;  // Distinct widths tell the files apart.
      ASSERT_TRUE(testing::WriteTiffFixture(Path(i), spec));
    }
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path Path(int i) const {
    std::string name = "f";  // append(), not operator+: GCC 12 -Wrestrict misfires at -O3.
    name.append(std::to_string(i)).append(".tif");
    return dir_ / name;
  }

  fs::path dir_;
};

TEST_F(TiffFileCacheTest, ReturnsTheSameHandleWhileCached) {
  TiffFileCache cache(TiffFile::Limits{}, 2);
  auto a = cache.Get(Path(0));
  ASSERT_TRUE(a.ok());
  EXPECT_EQ((*a)->ifd(0).width, 4u);
  auto again = cache.Get(Path(0));
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(a->get(), again->get());
}

TEST_F(TiffFileCacheTest, EvictsLeastRecentlyUsedAndKeepsBorrowedHandlesAlive) {
  TiffFileCache cache(TiffFile::Limits{}, 2);
  auto f0 = cache.Get(Path(0));
  auto f1 = cache.Get(Path(1));
  ASSERT_TRUE(cache.Get(Path(0)).ok());  // f0 is now the most recent.
  auto f2 = cache.Get(Path(2));          // Evicts f1.
  ASSERT_TRUE(f2.ok());
  EXPECT_EQ(cache.size(), 2u);
  EXPECT_EQ(cache.Get(Path(0))->get(), f0->get());  // Still cached.
  EXPECT_NE(cache.Get(Path(1))->get(), f1->get());  // Reopened: a new handle.
  // The evicted handle still works for the reader that holds it.
  std::vector<std::byte> plane(5 * 8 * 2);
  EXPECT_TRUE((*f1)->ReadPlane(0, 0, plane).ok());
}

// The files of a cache share one budget for kept decoded pages: with room for a page per file
// the samples of a chunky page are decoded once, with less each is decoded on its own.
TEST_F(TiffFileCacheTest, FilesShareTheBudgetForKeptPages) {
  testing::TiffFixtureSpec spec;  // 16 x 8 RGB uint16, deflate, in 3 strips: 768 bytes a page.
  spec.samples_per_pixel = 3;
  spec.compression = 8;
  ASSERT_TRUE(testing::WriteTiffFixture(dir_ / "rgb.tif", spec));
  const uint64_t page_bytes = 16 * 8 * 3 * 2;
  for (uint64_t budget : {4 * page_bytes, 4 * page_bytes - 1}) {
    TiffFile::Limits limits;
    limits.max_cached_bytes = budget;
    EXPECT_EQ(TiffFileCache::PerFileLimits(limits, 4).max_cached_bytes, budget / 4);
    TiffFileCache cache(limits, 4);
    auto file = cache.Get(dir_ / "rgb.tif");
    ASSERT_TRUE(file.ok()) << file.status().ToString();
    std::vector<std::byte> plane(16 * 8 * 2);
    for (int sample = 0; sample < 3; ++sample) {
      ASSERT_TRUE((*file)->ReadPlane(0, sample, plane).ok());
    }
    EXPECT_EQ((*file)->blocks_decoded(), budget / 4 >= page_bytes ? 3u : 9u) << budget;
  }
}

TEST_F(TiffFileCacheTest, ErrorsAreNotCached) {
  TiffFileCache cache(TiffFile::Limits{}, 2);
  EXPECT_FALSE(cache.Get(dir_ / "missing.tif").ok());
  EXPECT_EQ(cache.size(), 0u);
}

TEST_F(TiffFileCacheTest, ConcurrentGetsStayBounded) {
  TiffFileCache cache(TiffFile::Limits{}, 3);
  std::vector<std::thread> threads;
  std::atomic<int> failures = 0;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < 50; ++i) {
        auto f = cache.Get(Path((i + t) % 5));
        if (!f.ok() || (*f)->ifd(0).width != static_cast<uint32_t>(4 + (i + t) % 5)) ++failures;
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(failures, 0);
  EXPECT_LE(cache.size(), 3u);
}

}  // namespace
}  // namespace octoscope::io
