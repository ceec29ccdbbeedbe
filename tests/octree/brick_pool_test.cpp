#include "octree/brick_pool.h"

#include <gtest/gtest.h>

#include <cstring>
#include <vector>

#include "paging/memory_page_store.h"
#include "paging/page_cache.h"

namespace octoscope::octree {
namespace {

TEST(BrickPoolTest, IdsAreDenseAndFreedIdsAreReusedLowestFirst) {
  paging::MemoryPageStore store(1024);
  paging::PageCache cache(&store, 8 * 1024);
  BrickPool pool(&cache, 100, 10);
  for (uint32_t expected = 1; expected <= 6; ++expected) {
    auto id = pool.Allocate();
    ASSERT_TRUE(id.ok());
    EXPECT_EQ(*id, expected);
  }
  EXPECT_EQ(pool.live_bricks(), 6u);
  EXPECT_EQ(pool.pool_bytes(), 600u);
  pool.Free(5);
  pool.Free(2);
  pool.Free(2);   // Double free: ignored.
  pool.Free(0);   // Invalid: ignored.
  pool.Free(99);  // Never handed out: ignored.
  EXPECT_EQ(pool.live_bricks(), 4u);
  EXPECT_FALSE(pool.IsLive(2));
  EXPECT_TRUE(pool.IsLive(3));
  EXPECT_EQ(*pool.Allocate(), 2u);
  EXPECT_EQ(*pool.Allocate(), 5u);
  EXPECT_EQ(*pool.Allocate(), 7u);
  EXPECT_EQ(pool.live_bricks(), 7u);
}

TEST(BrickPoolTest, BricksMapToPagesAndSurviveEviction) {
  paging::MemoryPageStore store(1000);
  // Room for two pages only: writing 12 bricks of 3 pages forces write-back and reloads.
  paging::PageCache cache(&store, 2000);
  BrickPool pool(&cache, 300, 3);  // 3 bricks (900 bytes) per 1000-byte page.
  std::vector<uint32_t> ids;
  for (int i = 0; i < 9; ++i) ids.push_back(*pool.Allocate());
  EXPECT_EQ(pool.PageOf(1), 0u);
  EXPECT_EQ(pool.PageOf(3), 0u);
  EXPECT_EQ(pool.PageOf(4), 1u);
  EXPECT_EQ(pool.PageOf(9), 2u);
  for (uint32_t id : ids) {
    auto h = pool.Pin(id);
    ASSERT_TRUE(h.ok()) << h.status().ToString();
    h->MarkDirty();
    std::span<std::byte> d = h->data();
    ASSERT_EQ(d.size(), 300u);
    for (size_t i = 0; i < d.size(); ++i) d[i] = static_cast<std::byte>((id * 31 + i) & 0xff);
  }
  for (uint32_t id : ids) {
    auto h = pool.Pin(id);
    ASSERT_TRUE(h.ok());
    std::span<const std::byte> d = std::as_const(*h).data();
    for (size_t i = 0; i < d.size(); ++i) {
      ASSERT_EQ(d[i], static_cast<std::byte>((id * 31 + i) & 0xff))
          << "brick " << id << " byte " << i;
    }
  }
  EXPECT_GT(cache.stats().evictions, 0u);
  // The bytes are on the store at the documented place: brick 5 = page 1, offset 300.
  ASSERT_TRUE(cache.Flush().ok());
  auto page = store.PageContents(1);
  ASSERT_TRUE(page.has_value());
  EXPECT_EQ((*page)[300], static_cast<std::byte>((5 * 31) & 0xff));
}

TEST(BrickPoolTest, PinOfFreeBrickFailsAndTryPinNeverLoads) {
  paging::MemoryPageStore store(256);
  paging::PageCache cache(&store, 4096);
  BrickPool pool(&cache, 64, 4);
  EXPECT_FALSE(pool.Pin(1).ok());
  const uint32_t id = *pool.Allocate();
  EXPECT_FALSE(pool.TryPin(id).has_value());  // Not resident yet.
  { ASSERT_TRUE(pool.Pin(id).ok()); }
  EXPECT_TRUE(pool.TryPin(id).has_value());
  pool.Free(id);
  EXPECT_FALSE(pool.TryPin(id).has_value());
  EXPECT_EQ(pool.Pin(id).status().code(), StatusCode::kInvalidArgument);
}

TEST(BrickPoolTest, StateRoundTripsAndBadStatesAreRejected) {
  paging::MemoryPageStore store(256);
  paging::PageCache cache(&store, 4096);
  BrickPool pool(&cache, 64, 4);
  for (int i = 0; i < 5; ++i) (void)pool.Allocate();
  pool.Free(4);
  pool.Free(2);
  const BrickPool::State state = pool.ExportState();
  EXPECT_EQ(state.next_id, 6u);
  EXPECT_EQ(state.free_ids, (std::vector<uint32_t>{2, 4}));
  BrickPool other(&cache, 64, 4);
  ASSERT_TRUE(other.ImportState(state).ok());
  EXPECT_EQ(other.live_bricks(), 3u);
  EXPECT_EQ(*other.Allocate(), 2u);
  EXPECT_EQ(other.ImportState({6, {4, 2}}).code(), StatusCode::kCorrupt);  // Not ascending.
  EXPECT_EQ(other.ImportState({6, {6}}).code(), StatusCode::kCorrupt);     // Out of range.
  EXPECT_EQ(other.ImportState({6, {0}}).code(), StatusCode::kCorrupt);
  EXPECT_EQ(other.ImportState({0, {}}).code(), StatusCode::kCorrupt);
}

}  // namespace
}  // namespace octoscope::octree
