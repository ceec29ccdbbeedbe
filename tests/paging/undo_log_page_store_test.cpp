// UndoLogPageStore: a store modified in place after a checkpoint is put back exactly as the
// checkpoint left it — pages written once or many times, torn log tails and logs of another
// checkpoint included — and costs nothing for pages the checkpoint does not hold.
#include "paging/undo_log_page_store.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <memory>

#include "paging/file_page_store.h"
#include "paging/page_pattern.h"

namespace octoscope::paging {
namespace {

namespace fs = std::filesystem;
using testing::PageBytes;

constexpr uint64_t kPage = 4096;

class UndoLogPageStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("octoscope_undo_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::unique_ptr<PageStore> OpenPool(OpenMode mode) {
    auto store = OpenFilePageStore(dir_ / "pool", kPage, mode);
    EXPECT_TRUE(store.ok()) << store.status().ToString();
    return store.ok() ? std::move(*store) : nullptr;
  }
  // Page `page` of the pool file as it is on disk now.
  std::vector<std::byte> OnDisk(uint64_t page) {
    std::vector<std::byte> bytes(kPage);
    EXPECT_TRUE(OpenPool(OpenMode::kOpenExisting)->Read(page, bytes).ok());
    return bytes;
  }
  // A checkpoint of generation 3 holding pages 0..3 at version 1, with the store left open.
  std::unique_ptr<UndoLogPageStore> Checkpointed() {
    std::unique_ptr<PageStore> pool = OpenPool(OpenMode::kCreateTruncate);
    for (uint64_t p = 0; p < 4; ++p) EXPECT_TRUE(pool->Write(p, PageBytes(kPage, p, 1)).ok());
    EXPECT_TRUE(pool->Sync().ok());
    auto store = UndoLogPageStore::Create(std::move(pool), dir_ / "undo", 3);
    EXPECT_TRUE(store.ok()) << store.status().ToString();
    return store.ok() ? std::move(*store) : nullptr;
  }
  Result<uint64_t> RollBack(uint64_t generation) {
    std::unique_ptr<PageStore> pool = OpenPool(OpenMode::kOpenExisting);
    return UndoLogPageStore::RollBack(*pool, dir_ / "undo", generation);
  }

  fs::path dir_;
};

TEST_F(UndoLogPageStoreTest, RollBackRestoresTheCheckpointAfterInPlaceWrites) {
  std::unique_ptr<UndoLogPageStore> store = Checkpointed();
  ASSERT_NE(store, nullptr);
  // Rewritten (one page twice), and a page beyond the checkpoint.
  ASSERT_TRUE(store->Write(1, PageBytes(kPage, 1, 2)).ok());
  ASSERT_TRUE(store->Write(1, PageBytes(kPage, 1, 3)).ok());
  ASSERT_TRUE(store->Write(3, PageBytes(kPage, 3, 2)).ok());
  ASSERT_TRUE(store->Write(6, PageBytes(kPage, 6, 2)).ok());
  ASSERT_TRUE(store->Sync().ok());
  EXPECT_EQ(store->logged_pages(), 2u);  // Pages 1 and 3, each once; page 6 is not protected.
  EXPECT_EQ(OnDisk(1), PageBytes(kPage, 1, 3));
  store.reset();  // The process dies: the log stays.

  auto restored = RollBack(3);
  ASSERT_TRUE(restored.ok()) << restored.status().ToString();
  EXPECT_EQ(*restored, 2u);
  for (uint64_t p = 0; p < 4; ++p) EXPECT_EQ(OnDisk(p), PageBytes(kPage, p, 1)) << "page " << p;
  // Idempotent (a crash during the rollback rolls back again).
  EXPECT_EQ(RollBack(3).value(), 2u);
  EXPECT_EQ(OnDisk(1), PageBytes(kPage, 1, 1));
}

TEST_F(UndoLogPageStoreTest, ANewCheckpointEmptiesTheLogAndProtectsWhatWasWritten) {
  std::unique_ptr<UndoLogPageStore> store = Checkpointed();
  ASSERT_NE(store, nullptr);
  ASSERT_TRUE(store->Write(2, PageBytes(kPage, 2, 2)).ok());
  ASSERT_TRUE(store->Write(5, PageBytes(kPage, 5, 2)).ok());
  ASSERT_TRUE(store->Sync().ok());
  ASSERT_TRUE(store->Restart(4).ok());  // Checkpoint 4: pages 0..5 as they are now.
  EXPECT_EQ(store->logged_pages(), 0u);
  ASSERT_TRUE(store->Write(5, PageBytes(kPage, 5, 3)).ok());
  store.reset();
  // The log of checkpoint 3 is gone; a checkpoint-3 rollback (a MANIFEST not yet replaced) finds
  // nothing of its own, checkpoint 4's restores page 5.
  EXPECT_EQ(RollBack(3).value(), 0u);
  EXPECT_EQ(OnDisk(5), PageBytes(kPage, 5, 3));
  EXPECT_EQ(RollBack(4).value(), 1u);
  EXPECT_EQ(OnDisk(5), PageBytes(kPage, 5, 2));
  EXPECT_EQ(OnDisk(2), PageBytes(kPage, 2, 2));
}

TEST_F(UndoLogPageStoreTest, ATornLastEntryIsIgnoredAndAMissingLogRestoresNothing) {
  std::unique_ptr<UndoLogPageStore> store = Checkpointed();
  ASSERT_NE(store, nullptr);
  ASSERT_TRUE(store->Write(0, PageBytes(kPage, 0, 2)).ok());
  ASSERT_TRUE(store->Write(2, PageBytes(kPage, 2, 2)).ok());
  store.reset();
  // The second entry was cut short by the crash (its page was then never overwritten).
  fs::resize_file(dir_ / "undo", fs::file_size(dir_ / "undo") - 100);
  EXPECT_EQ(RollBack(3).value(), 1u);
  EXPECT_EQ(OnDisk(0), PageBytes(kPage, 0, 1));
  EXPECT_EQ(OnDisk(2), PageBytes(kPage, 2, 2));
  fs::remove(dir_ / "undo");
  EXPECT_EQ(RollBack(3).value(), 0u);
}

}  // namespace
}  // namespace octoscope::paging
