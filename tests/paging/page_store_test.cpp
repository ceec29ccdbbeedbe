// Tests of the PageStore implementations: MemoryPageStore, FilePageStore and the test-only
// FaultInjectingPageStore.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <csignal>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "paging/fault_injecting_page_store.h"
#include "paging/file_page_store.h"
#include "paging/memory_page_store.h"
#include "paging/page_pattern.h"

namespace octoscope::paging {
namespace {

using testing::FillPage;
using testing::PageBytes;
using testing::PageIs;
using testing::PageIsZero;

constexpr uint64_t kPage = 256;

// A fresh directory under the test temp dir, removed at the end of the test.
class TempDir {
 public:
  TempDir() {
    static std::atomic<int> counter{0};
    path_ = std::filesystem::path(::testing::TempDir()) /
            ("octoscope_paging_" + std::to_string(::getpid()) + "_" +
             std::to_string(counter.fetch_add(1)));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// --- MemoryPageStore ---------------------------------------------------------------------------

TEST(MemoryPageStoreTest, NeverWrittenPagesReadAsZerosAndWritesRoundTrip) {
  MemoryPageStore store(kPage);
  EXPECT_EQ(store.page_bytes(), kPage);
  EXPECT_EQ(store.page_count(), 0u);
  std::vector<std::byte> buf(kPage, std::byte{0xAB});
  ASSERT_TRUE(store.Read(7, buf).ok());
  EXPECT_TRUE(PageIsZero(buf));
  EXPECT_EQ(store.page_count(), 0u);  // Reading does not grow the store.

  ASSERT_TRUE(store.Write(3, PageBytes(kPage, 3, 1)).ok());
  ASSERT_TRUE(store.Write(3, PageBytes(kPage, 3, 2)).ok());
  ASSERT_TRUE(store.Write(1, PageBytes(kPage, 1, 9)).ok());
  EXPECT_EQ(store.page_count(), 4u);
  ASSERT_TRUE(store.Read(3, buf).ok());
  EXPECT_TRUE(PageIs(buf, 3, 2));
  ASSERT_TRUE(store.Read(1, buf).ok());
  EXPECT_TRUE(PageIs(buf, 1, 9));
  ASSERT_TRUE(store.Read(2, buf).ok());
  EXPECT_TRUE(PageIsZero(buf));

  EXPECT_EQ(store.write_count(3), 2u);
  EXPECT_EQ(store.write_count(1), 1u);
  EXPECT_EQ(store.write_count(2), 0u);
  EXPECT_EQ(store.read_count(3), 1u);
  EXPECT_EQ(store.read_count(7), 1u);
  EXPECT_EQ(store.writes(), 3u);
  EXPECT_EQ(store.reads(), 4u);
  EXPECT_FALSE(store.PageContents(2).has_value());
  EXPECT_FALSE(store.PageContents(7).has_value());
  ASSERT_TRUE(store.PageContents(1).has_value());
  EXPECT_TRUE(PageIs(*store.PageContents(1), 1, 9));
  ASSERT_TRUE(store.Sync().ok());
  EXPECT_EQ(store.syncs(), 1u);
}

TEST(MemoryPageStoreTest, WrongBufferSizeIsInvalidArgument) {
  MemoryPageStore store(kPage);
  std::vector<std::byte> small(kPage - 1);
  EXPECT_EQ(store.Read(0, small).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(store.Write(0, small).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(store.page_count(), 0u);
}

// --- FilePageStore -----------------------------------------------------------------------------

TEST(FilePageStoreTest, RoundTripAndReopen) {
  TempDir dir;
  const auto path = dir.path() / "pages.bin";
  {
    auto store = OpenFilePageStore(path, kPage, OpenMode::kCreateTruncate);
    ASSERT_TRUE(store.ok()) << store.status().ToString();
    EXPECT_EQ((*store)->page_bytes(), kPage);
    EXPECT_EQ((*store)->page_count(), 0u);
    ASSERT_TRUE((*store)->Write(0, PageBytes(kPage, 0, 5)).ok());
    ASSERT_TRUE((*store)->Write(4, PageBytes(kPage, 4, 6)).ok());  // Leaves a hole: 1..3.
    ASSERT_TRUE((*store)->Write(0, PageBytes(kPage, 0, 7)).ok());  // Overwrite.
    EXPECT_EQ((*store)->page_count(), 5u);
    std::vector<std::byte> buf(kPage);
    ASSERT_TRUE((*store)->Read(0, buf).ok());
    EXPECT_TRUE(PageIs(buf, 0, 7));
    ASSERT_TRUE((*store)->Sync().ok());
  }
  EXPECT_EQ(std::filesystem::file_size(path), 5 * kPage);

  auto store = OpenFilePageStore(path, kPage, OpenMode::kOpenExisting);
  ASSERT_TRUE(store.ok()) << store.status().ToString();
  EXPECT_EQ((*store)->page_count(), 5u);
  std::vector<std::byte> buf(kPage, std::byte{1});
  ASSERT_TRUE((*store)->Read(0, buf).ok());
  EXPECT_TRUE(PageIs(buf, 0, 7));
  ASSERT_TRUE((*store)->Read(4, buf).ok());
  EXPECT_TRUE(PageIs(buf, 4, 6));
  for (uint64_t hole : {1, 2, 3, 5, 1000}) {  // Holes and pages past the end read as zeros.
    std::fill(buf.begin(), buf.end(), std::byte{1});
    ASSERT_TRUE((*store)->Read(hole, buf).ok());
    EXPECT_TRUE(PageIsZero(buf)) << "page " << hole;
  }
}

TEST(FilePageStoreTest, CreateTruncateEmptiesAnExistingFile) {
  TempDir dir;
  const auto path = dir.path() / "pages.bin";
  {
    auto store = OpenFilePageStore(path, kPage, OpenMode::kCreateTruncate);
    ASSERT_TRUE(store.ok());
    ASSERT_TRUE((*store)->Write(2, PageBytes(kPage, 2, 1)).ok());
  }
  auto store = OpenFilePageStore(path, kPage, OpenMode::kCreateTruncate);
  ASSERT_TRUE(store.ok());
  EXPECT_EQ((*store)->page_count(), 0u);
  std::vector<std::byte> buf(kPage);
  ASSERT_TRUE((*store)->Read(2, buf).ok());
  EXPECT_TRUE(PageIsZero(buf));
}

TEST(FilePageStoreTest, TornLastPageCountsAndReadsZerosAfterTheTail) {
  TempDir dir;
  const auto path = dir.path() / "pages.bin";
  {
    auto store = OpenFilePageStore(path, kPage, OpenMode::kCreateTruncate);
    ASSERT_TRUE(store.ok());
    ASSERT_TRUE((*store)->Write(0, PageBytes(kPage, 0, 1)).ok());
    ASSERT_TRUE((*store)->Write(1, PageBytes(kPage, 1, 1)).ok());
  }
  // Simulate a crash in the middle of writing page 1.
  std::filesystem::resize_file(path, kPage + 100);
  auto store = OpenFilePageStore(path, kPage, OpenMode::kOpenExisting);
  ASSERT_TRUE(store.ok());
  EXPECT_EQ((*store)->page_count(), 2u);
  std::vector<std::byte> buf(kPage, std::byte{1});
  ASSERT_TRUE((*store)->Read(1, buf).ok());
  const auto expected = PageBytes(kPage, 1, 1);
  EXPECT_TRUE(std::equal(buf.begin(), buf.begin() + 100, expected.begin()));
  EXPECT_TRUE(PageIsZero(std::span(buf).subspan(100)));
}

TEST(FilePageStoreTest, BadArgumentsAndMissingFilesAreErrorsNamingTheFile) {
  TempDir dir;
  const auto missing = dir.path() / "missing.bin";
  auto r = OpenFilePageStore(missing, kPage, OpenMode::kOpenExisting);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kNotFound);
  EXPECT_NE(r.status().message().find(missing.string()), std::string::npos) << r.status().message();
  EXPECT_FALSE(std::filesystem::exists(missing));  // kOpenExisting never creates.

  r = OpenFilePageStore(dir.path() / "a.bin", 0, OpenMode::kCreateTruncate);
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  r = OpenFilePageStore(dir.path() / "a.bin", kMaxPageBytes + 1, OpenMode::kCreateTruncate);
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);

  r = OpenFilePageStore(dir.path(), kPage, OpenMode::kOpenExisting);  // A directory.
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find(dir.path().string()), std::string::npos);

  r = OpenFilePageStore(dir.path() / "no_such_dir" / "a.bin", kPage, OpenMode::kCreateTruncate);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kIoError);
  EXPECT_NE(r.status().message().find("no_such_dir"), std::string::npos);
}

TEST(FilePageStoreTest, WrongSizesAndHugeOffsetsAreRejected) {
  TempDir dir;
  const auto path = dir.path() / "pages.bin";
  auto store = OpenFilePageStore(path, kPage, OpenMode::kCreateTruncate);
  ASSERT_TRUE(store.ok());
  std::vector<std::byte> small(kPage / 2);
  Status s = (*store)->Read(0, small);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find(path.string()), std::string::npos) << s.message();
  EXPECT_EQ((*store)->Write(0, small).code(), StatusCode::kInvalidArgument);

  std::vector<std::byte> page(kPage);
  // page * page_bytes overflows 64 bits / does not fit off_t.
  EXPECT_EQ((*store)->Write(UINT64_MAX / 2, page).code(), StatusCode::kOutOfRange);
  EXPECT_EQ((*store)->Read(UINT64_MAX, page).code(), StatusCode::kOutOfRange);
  EXPECT_EQ((*store)->page_count(), 0u);
}

TEST(FilePageStoreTest, DeviceFilesAreRejected) {
  if (!std::filesystem::exists("/dev/full")) GTEST_SKIP() << "no /dev/full";
  auto store = OpenFilePageStore("/dev/full", kPage, OpenMode::kOpenExisting);
  ASSERT_FALSE(store.ok());
  EXPECT_EQ(store.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(store.status().message().find("/dev/full"), std::string::npos);
}

TEST(FilePageStoreTest, OsWriteErrorsNameTheFileAndPage) {
  // Make pwrite fail for real: a file-size limit turns writes past it into EFBIG.
  TempDir dir;
  const auto path = dir.path() / "pages.bin";
  auto store = OpenFilePageStore(path, kPage, OpenMode::kCreateTruncate);
  ASSERT_TRUE(store.ok());
  struct rlimit old_limit;
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &old_limit), 0);
  auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
  struct rlimit limit = old_limit;
  limit.rlim_cur = 2 * kPage;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &limit), 0);
  Status in_limit = (*store)->Write(1, PageBytes(kPage, 1, 1));
  Status past_limit = (*store)->Write(5, PageBytes(kPage, 5, 1));
  ::setrlimit(RLIMIT_FSIZE, &old_limit);
  std::signal(SIGXFSZ, old_handler);

  EXPECT_TRUE(in_limit.ok()) << in_limit.ToString();
  ASSERT_FALSE(past_limit.ok());
  EXPECT_EQ(past_limit.code(), StatusCode::kIoError);
  EXPECT_NE(past_limit.message().find(path.string()), std::string::npos) << past_limit.message();
  EXPECT_NE(past_limit.message().find("page 5"), std::string::npos) << past_limit.message();
  EXPECT_EQ((*store)->page_count(), 2u);  // The failed write did not count.
}

TEST(FilePageStoreTest, ManyThreadsWriteAndReadDifferentPages) {
  TempDir dir;
  auto store = OpenFilePageStore(dir.path() / "pages.bin", kPage, OpenMode::kCreateTruncate);
  ASSERT_TRUE(store.ok());
  PageStore* s = store->get();
  constexpr int kThreads = 4, kPagesPerThread = 32;
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      std::vector<std::byte> buf(kPage);
      for (int round = 1; round <= 3; ++round) {
        for (int i = 0; i < kPagesPerThread; ++i) {
          const uint64_t page = static_cast<uint64_t>(i * kThreads + t);  // Interleaved pages.
          FillPage(buf, page, round);
          if (!s->Write(page, buf).ok()) failures.fetch_add(1);
          if (!s->Read(page, buf).ok() || !PageIs(buf, page, round)) failures.fetch_add(1);
        }
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(failures.load(), 0);
  EXPECT_EQ(s->page_count(), uint64_t{kThreads * kPagesPerThread});
  std::vector<std::byte> buf(kPage);
  for (uint64_t page = 0; page < kThreads * kPagesPerThread; ++page) {
    ASSERT_TRUE(s->Read(page, buf).ok());
    EXPECT_TRUE(PageIs(buf, page, 3));
  }
}

// --- FaultInjectingPageStore ---------------------------------------------------------------------

TEST(FaultInjectingPageStoreTest, FailsExactlyTheChosenOperations) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  std::vector<std::byte> buf(kPage);
  store.FailNthWrite(2);
  EXPECT_TRUE(store.Write(0, PageBytes(kPage, 0, 1)).ok());
  EXPECT_EQ(store.Write(1, PageBytes(kPage, 1, 1)).code(), StatusCode::kIoError);
  EXPECT_TRUE(store.Write(1, PageBytes(kPage, 1, 2)).ok());
  EXPECT_EQ(inner.write_count(1), 1u);

  store.FailNthRead(1);
  EXPECT_EQ(store.Read(0, buf).code(), StatusCode::kIoError);
  EXPECT_TRUE(store.Read(0, buf).ok());
  EXPECT_TRUE(PageIs(buf, 0, 1));

  store.FailWritesOfPage(1);
  store.SetTornWriteBytes(20);
  EXPECT_FALSE(store.Write(1, PageBytes(kPage, 1, 3)).ok());
  auto torn = inner.PageContents(1);
  ASSERT_TRUE(torn.has_value());
  EXPECT_EQ(testing::PageVersion(*torn), 3u);  // The new header made it …
  EXPECT_FALSE(PageIs(*torn, 1, 3));           // … but not the whole page …
  const auto old = PageBytes(kPage, 1, 2);     // … and the rest is the old page.
  EXPECT_TRUE(std::equal(torn->begin() + 20, torn->end(), old.begin() + 20));
  EXPECT_TRUE(store.Write(0, PageBytes(kPage, 0, 2)).ok());  // Other pages unaffected.

  store.FailSync(true);
  EXPECT_FALSE(store.Sync().ok());
  store.FailSync(false);
  EXPECT_TRUE(store.Sync().ok());
  EXPECT_EQ(store.failed_writes(), 2u);
  EXPECT_EQ(store.failed_reads(), 1u);
}

}  // namespace
}  // namespace octoscope::paging
