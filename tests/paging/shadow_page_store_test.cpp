// ShadowPageStore: between two checkpoints the wrapped store keeps exactly the checkpoint's
// pages (writes of them go to the shadow, and read back from there), a checkpoint copies them in,
// and a copy cut short by a crash is finished from the checkpoint's map — never from a shadow of
// later writes.
#include "paging/shadow_page_store.h"

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

class ShadowPageStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("octoscope_shadow_" + std::to_string(::getpid()) + "_" +
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
  std::vector<std::byte> Through(PageStore& store, uint64_t page) {
    std::vector<std::byte> bytes(kPage);
    EXPECT_TRUE(store.Read(page, bytes).ok());
    return bytes;
  }
  // A checkpoint of generation 3 holding pages 0..3 at version 1, its shadow empty.
  std::unique_ptr<ShadowPageStore> Checkpointed() {
    std::unique_ptr<PageStore> pool = OpenPool(OpenMode::kCreateTruncate);
    for (uint64_t p = 0; p < 4; ++p) EXPECT_TRUE(pool->Write(p, PageBytes(kPage, p, 1)).ok());
    EXPECT_TRUE(pool->Sync().ok());
    auto store = ShadowPageStore::Create(std::move(pool), dir_ / "shadow", 3);
    EXPECT_TRUE(store.ok()) << store.status().ToString();
    return store.ok() ? std::move(*store) : nullptr;
  }
  Result<uint64_t> Recover(const ShadowMap& map) {
    std::unique_ptr<PageStore> pool = OpenPool(OpenMode::kOpenExisting);
    return ShadowPageStore::Recover(*pool, dir_ / "shadow", map);
  }

  fs::path dir_;
};

TEST_F(ShadowPageStoreTest, TheCheckpointsPagesStayInPlaceUntilTheNextCheckpoint) {
  std::unique_ptr<ShadowPageStore> store = Checkpointed();
  ASSERT_NE(store, nullptr);
  // Rewritten (one page twice), and a page beyond the checkpoint.
  ASSERT_TRUE(store->Write(1, PageBytes(kPage, 1, 2)).ok());
  ASSERT_TRUE(store->Write(1, PageBytes(kPage, 1, 3)).ok());
  ASSERT_TRUE(store->Write(3, PageBytes(kPage, 3, 2)).ok());
  ASSERT_TRUE(store->Write(6, PageBytes(kPage, 6, 2)).ok());
  ASSERT_TRUE(store->Sync().ok());
  EXPECT_EQ(store->shadowed_pages(), 2u);  // Pages 1 and 3, one slot each.
  EXPECT_EQ(Through(*store, 1), PageBytes(kPage, 1, 3));
  EXPECT_EQ(Through(*store, 3), PageBytes(kPage, 3, 2));
  EXPECT_EQ(Through(*store, 0), PageBytes(kPage, 0, 1));
  EXPECT_EQ(OnDisk(1), PageBytes(kPage, 1, 1));  // The pool: still the checkpoint's.
  EXPECT_EQ(OnDisk(3), PageBytes(kPage, 3, 1));
  EXPECT_EQ(OnDisk(6), PageBytes(kPage, 6, 2));  // Not the checkpoint's: in place.
  EXPECT_EQ(fs::file_size(dir_ / "shadow"), 40 + 2 * kPage);
  store.reset();  // The process dies.
  EXPECT_EQ(ShadowPageStore::PagesWrittenSince(dir_ / "shadow", 3), 2u);
  EXPECT_EQ(ShadowPageStore::PagesWrittenSince(dir_ / "shadow", 2), 0u);
  for (uint64_t p = 0; p < 4; ++p) EXPECT_EQ(OnDisk(p), PageBytes(kPage, p, 1)) << "page " << p;
}

TEST_F(ShadowPageStoreTest, ACheckpointCopiesTheShadowInAndACopyCutShortIsFinished) {
  std::unique_ptr<ShadowPageStore> store = Checkpointed();
  ASSERT_NE(store, nullptr);
  ASSERT_TRUE(store->Write(2, PageBytes(kPage, 2, 2)).ok());
  ASSERT_TRUE(store->Write(0, PageBytes(kPage, 0, 2)).ok());
  ASSERT_TRUE(store->Sync().ok());
  const ShadowMap map = store->Freeze();
  EXPECT_EQ(map.generation, 3u);
  EXPECT_EQ(map.slots, (std::map<uint64_t, uint64_t>{{0, 1}, {2, 0}}));
  // The owner's checkpoint 4 is durable with `map`; the process dies before Apply.
  store.reset();
  EXPECT_EQ(Recover(map).value(), 2u);
  EXPECT_EQ(OnDisk(0), PageBytes(kPage, 0, 2));
  EXPECT_EQ(OnDisk(2), PageBytes(kPage, 2, 2));
  EXPECT_EQ(Recover(map).value(), 2u);  // Again after a crash during the recovery: the same.

  // Applied: the pool holds the checkpoint; the next generation protects what was written; a
  // later recovery with the old map copies nothing (the shadow now holds later writes).
  auto reopened = ShadowPageStore::Create(OpenPool(OpenMode::kOpenExisting), dir_ / "shadow", 4);
  ASSERT_TRUE(reopened.ok());
  ASSERT_TRUE((*reopened)->Write(2, PageBytes(kPage, 2, 3)).ok());
  ASSERT_TRUE((*reopened)->Sync().ok());
  const ShadowMap next = (*reopened)->Freeze();
  ASSERT_TRUE((*reopened)->Apply(5).ok());
  EXPECT_EQ((*reopened)->shadowed_pages(), 0u);
  EXPECT_EQ(OnDisk(2), PageBytes(kPage, 2, 3));
  ASSERT_TRUE((*reopened)->Write(2, PageBytes(kPage, 2, 4)).ok());  // Generation 5's shadow.
  ASSERT_TRUE((*reopened)->Sync().ok());
  reopened->reset();
  EXPECT_EQ(Recover(map).value(), 0u);
  EXPECT_EQ(Recover(next).value(), 0u);
  EXPECT_EQ(OnDisk(2), PageBytes(kPage, 2, 3));
}

TEST_F(ShadowPageStoreTest, MapsAreReadStrictly) {
  ShadowMap map;
  map.generation = 9;
  map.page_bytes = kPage;
  map.slots = {{3, 1}, {7, 0}};
  const std::string bytes = map.Serialize();
  EXPECT_EQ(ShadowMap::Parse(bytes).value(), map);
  EXPECT_EQ(ShadowMap::Parse(bytes.substr(0, bytes.size() - 1)).status().code(),
            StatusCode::kCorrupt);
  std::string unordered = bytes;
  std::swap_ranges(unordered.begin() + 40, unordered.begin() + 48, unordered.begin() + 56);
  EXPECT_EQ(ShadowMap::Parse(unordered).status().code(), StatusCode::kCorrupt);
  std::string slot_out_of_range = bytes;
  slot_out_of_range[48] = 5;
  EXPECT_EQ(ShadowMap::Parse(slot_out_of_range).status().code(), StatusCode::kCorrupt);
  EXPECT_EQ(ShadowMap::Parse("OCTOSMAX" + bytes.substr(8)).status().code(), StatusCode::kCorrupt);
}

}  // namespace
}  // namespace octoscope::paging
