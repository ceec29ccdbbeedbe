// Tests of PageCache::SetBudget (the budget changed at run time) and of buffer reuse / zero pages.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "paging/cache_test_helpers.h"
#include "paging/fault_injecting_page_store.h"
#include "paging/memory_page_store.h"
#include "paging/page_cache.h"
#include "paging/page_pattern.h"

namespace octoscope::paging {
namespace {

using namespace std::chrono_literals;
using testing::CachedPageIs;
using testing::FillPage;
using testing::Hammer;
using testing::PageBytes;
using testing::PageIs;
using testing::PageIsZero;
using testing::WaitUntil;
using testing::WritePage;

constexpr uint64_t kPage = 256;

uint64_t ResidentPages(const PageCache& cache) { return cache.stats().resident_bytes / kPage; }

TEST(PageCacheBudgetTest, ShrinkWritesBackDirtyPagesOldestFirstAndTheyStayReadable) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 8 * kPage);
  for (uint64_t p = 0; p < 8; ++p) {
    if (p % 2 == 0) {
      WritePage(cache, p, p + 10);  // Dirty.
    } else {
      ASSERT_TRUE(cache.Pin(p).ok());  // Clean.
    }
  }
  EXPECT_EQ(store.writes(), 0u);
  ASSERT_TRUE(cache.SetBudget(3 * kPage + 7).ok());
  EXPECT_EQ(cache.budget_bytes(), 3 * kPage + 7);
  EXPECT_EQ(cache.capacity_pages(), 3u);
  auto stats = cache.stats();
  EXPECT_EQ(stats.budget_bytes, 3 * kPage + 7);
  EXPECT_EQ(stats.resident_bytes, 3 * kPage);
  EXPECT_EQ(stats.evictions, 5u);
  // The five least recently used pages (0..4) went; the dirty ones among them were written.
  for (uint64_t p : {0, 2, 4}) {
    ASSERT_TRUE(store.PageContents(p).has_value()) << p;
    EXPECT_TRUE(PageIs(*store.PageContents(p), p, p + 10));
  }
  EXPECT_EQ(store.writes(), 3u);
  for (uint64_t p : {5, 6, 7}) EXPECT_TRUE(cache.IsResident(p)) << p;
  EXPECT_EQ(stats.dirty_pages, 1u);  // Page 6.
  // Everything reads back, through the smaller cache.
  for (uint64_t p = 0; p < 8; p += 2) EXPECT_TRUE(CachedPageIs(cache, p, p + 10)) << p;
  EXPECT_LE(ResidentPages(cache), 3u);
  ASSERT_TRUE(cache.Flush().ok());
  EXPECT_TRUE(PageIs(*store.PageContents(6), 6, 16));
  EXPECT_EQ(cache.stats().peak_resident_bytes, 8 * kPage);
}

TEST(PageCacheBudgetTest, ShrinkKeepsPagesWhoseWriteBackFailsAndConvergesLater) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, 4 * kPage);
  for (uint64_t p = 0; p < 4; ++p) WritePage(cache, p, p + 1);
  store.FailWritesWhere([](uint64_t page) { return page == 1 || page == 2; });
  store.SetTornWriteBytes(kPage / 2);
  Status status = cache.SetBudget(kPage);
  EXPECT_EQ(status.code(), StatusCode::kIoError);
  EXPECT_NE(status.message().find("page 1"), std::string::npos) << status.message();
  EXPECT_NE(status.message().find("shrink"), std::string::npos) << status.message();
  // Pages 0 and 3 were written and dropped; 1 and 2 stay, whole and dirty, above the budget.
  EXPECT_EQ(ResidentPages(cache), 2u);
  EXPECT_EQ(cache.stats().dirty_pages, 2u);
  for (uint64_t p : {1, 2}) {
    auto kept = cache.TryPin(p);
    ASSERT_TRUE(kept.has_value());
    EXPECT_TRUE(PageIs(kept->data(), p, p + 1));
    EXPECT_FALSE(PageIs(*inner.PageContents(p), p, p + 1));  // Torn on "disk".
  }
  for (uint64_t p : {0, 3}) EXPECT_TRUE(PageIs(*inner.PageContents(p), p, p + 1)) << p;
  // No new page is admitted above the budget: a miss must first write back, which still fails.
  EXPECT_EQ(cache.Pin(9).status().code(), StatusCode::kIoError);
  EXPECT_EQ(ResidentPages(cache), 2u);

  store.FailWritesWhere(nullptr);
  ASSERT_TRUE(cache.SetBudget(kPage).ok());
  EXPECT_EQ(ResidentPages(cache), 1u);
  for (uint64_t p = 0; p < 4; ++p) EXPECT_TRUE(CachedPageIs(cache, p, p + 1)) << p;
  ASSERT_TRUE(cache.Flush().ok());
  for (uint64_t p = 0; p < 4; ++p) EXPECT_TRUE(PageIs(*inner.PageContents(p), p, p + 1)) << p;
}

TEST(PageCacheBudgetTest, ShrinkBelowPinnedPagesConvergesAsTheyAreUnpinned) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 6 * kPage, 40ms);
  std::vector<PageHandle> held;
  for (uint64_t p = 0; p < 4; ++p) {
    auto h = cache.Pin(p);
    ASSERT_TRUE(h.ok());
    if (p % 2 == 0) {  // Pages 0 and 2 dirty, 1 and 3 clean.
      h->MarkDirty();
      FillPage(h->data(), p, 5);
    }
    held.push_back(std::move(h).value());
  }
  WritePage(cache, 4, 5);          // Unpinned, dirty.
  ASSERT_TRUE(cache.Pin(5).ok());  // Unpinned, clean.
  ASSERT_EQ(ResidentPages(cache), 6u);

  ASSERT_TRUE(cache.SetBudget(2 * kPage).ok());  // Pinned pages are not an error.
  EXPECT_EQ(ResidentPages(cache), 4u);           // Only the 4 pinned pages are left.
  EXPECT_TRUE(PageIs(*store.PageContents(4), 4, 5));

  // Hits on pinned pages still work; a miss is never admitted above the budget.
  EXPECT_TRUE(cache.Pin(0).ok());
  auto miss = cache.Pin(10);
  ASSERT_FALSE(miss.ok());
  EXPECT_EQ(miss.status().code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(ResidentPages(cache), 4u);

  held[1].Reset();  // Clean: dropped by the unpin itself.
  EXPECT_EQ(ResidentPages(cache), 3u);
  EXPECT_FALSE(cache.IsResident(1));
  held[0].Reset();  // Dirty: stays until someone writes it back (no I/O in Unpin).
  EXPECT_EQ(ResidentPages(cache), 3u);
  EXPECT_EQ(store.write_count(0), 0u);
  // A miss writes it back and drops it, but the pinned pages 2 and 3 alone fill the budget: the
  // miss is still not admitted.
  EXPECT_EQ(cache.Pin(10).status().code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(ResidentPages(cache), 2u);
  EXPECT_TRUE(PageIs(*store.PageContents(0), 0, 5));
  held.clear();
  ASSERT_TRUE(cache.Pin(10).ok());
  EXPECT_EQ(ResidentPages(cache), 2u);
  ASSERT_TRUE(cache.Flush().ok());
  EXPECT_LE(ResidentPages(cache), 2u);
  EXPECT_EQ(cache.stats().peak_resident_bytes, 6 * kPage);
  for (uint64_t p : {0, 2, 4}) EXPECT_TRUE(CachedPageIs(cache, p, 5)) << p;
  EXPECT_LE(ResidentPages(cache), 2u);
}

TEST(PageCacheBudgetTest, GrowingWakesAPinWaitingForRoom) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 2 * kPage);  // Default pin timeout: 60 s.
  auto a = cache.Pin(0);
  auto b = cache.Pin(1);
  ASSERT_TRUE(a.ok() && b.ok());
  std::atomic<bool> returned{false};
  auto waiter = std::async(std::launch::async, [&] {
    auto h = cache.Pin(2);
    returned = true;
    return h.ok() ? Status::Ok() : h.status();
  });
  std::this_thread::sleep_for(30ms);
  EXPECT_FALSE(returned.load());  // Both pages stay pinned: it waits.
  ASSERT_TRUE(cache.SetBudget(3 * kPage).ok());
  // Woken by the budget change, not by the 60 s timeout (the test would take a minute otherwise).
  EXPECT_TRUE(waiter.get().ok());
  EXPECT_TRUE(cache.IsResident(0));
  EXPECT_TRUE(cache.IsResident(1));
  EXPECT_EQ(ResidentPages(cache), 3u);
}

TEST(PageCacheBudgetTest, BudgetBelowOnePageFailsWaitersAndMissesAtOnceButHitsWork) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, kPage);
  auto a = cache.Pin(0);
  ASSERT_TRUE(a.ok());
  auto waiter = std::async(std::launch::async, [&] { return cache.Pin(1).status(); });
  std::this_thread::sleep_for(20ms);
  ASSERT_TRUE(cache.SetBudget(kPage - 1).ok());
  EXPECT_EQ(waiter.get().code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(cache.capacity_pages(), 0u);
  EXPECT_TRUE(cache.Pin(0).ok());  // A hit on the pinned page.
  EXPECT_TRUE(cache.TryPin(0).has_value());
  a->Reset();
  EXPECT_EQ(cache.stats().resident_bytes, 0u);  // Clean and above the budget: dropped.
  EXPECT_EQ(cache.Pin(0).status().code(), StatusCode::kResourceExhausted);
  ASSERT_TRUE(cache.SetBudget(kPage).ok());
  EXPECT_TRUE(cache.Pin(0).ok());
}

TEST(PageCacheBudgetTest, BudgetChangesWhileThreadsHammerLoseNoData) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 12 * kPage);
  std::mt19937 rng(5);
  std::atomic<uint64_t> largest{12 * kPage};
  Hammer(&store, cache, 40, 4, 2000, /*retry_errors=*/false, [&] {
    // Between 8 and 16 pages: the 4 workers + TryPin hold at most 5 pins, so Pins never time out.
    const uint64_t bytes = (8 + rng() % 9) * kPage;
    if (bytes > largest.load()) largest = bytes;
    EXPECT_TRUE(cache.SetBudget(bytes).ok());
    std::this_thread::sleep_for(1ms);
  });
  EXPECT_LE(cache.stats().peak_resident_bytes, largest.load());
  EXPECT_GT(cache.stats().evictions, 0u);
}

// --- Buffers and zero pages ----------------------------------------------------------------------

TEST(PageCacheBufferTest, ALoadAtFullCacheReusesTheEvictedBuffer) {
  MemoryPageStore store(kPage);
  ASSERT_TRUE(store.Write(100, PageBytes(kPage, 100, 3)).ok());
  PageCache cache(&store, 2 * kPage);
  WritePage(cache, 0, 1);
  WritePage(cache, 1, 1);
  EXPECT_EQ(cache.stats().buffer_allocations, 2u);
  for (uint64_t p = 2; p < 40; ++p) WritePage(cache, p, 1);              // Never-written pages.
  for (int i = 0; i < 5; ++i) EXPECT_TRUE(CachedPageIs(cache, 100, 3));  // A stored page.
  for (uint64_t p = 0; p < 40; ++p) EXPECT_TRUE(CachedPageIs(cache, p, 1)) << p;
  const auto stats = cache.stats();
  EXPECT_EQ(stats.buffer_allocations, 2u);  // Every later load took an evicted page's buffer.
  EXPECT_GT(stats.evictions, 70u);
}

TEST(PageCacheBufferTest, NeverWrittenPagesAreZerosWithoutAStoreReadEvenInReusedBuffers) {
  MemoryPageStore inner(kPage);
  ASSERT_TRUE(inner.Write(2, PageBytes(kPage, 2, 1)).ok());  // page_count() = 3.
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, kPage);  // One page: every load reuses the previous buffer.
  WritePage(cache, 5, 9);          // Dirty garbage in the one buffer.
  {
    auto h = cache.Pin(6);  // Reuses page 5's buffer: must be cleared, not show page 5.
    ASSERT_TRUE(h.ok());
    EXPECT_TRUE(PageIsZero(h->data()));
  }
  {
    auto h = cache.Pin(1);  // A hole below page_count(): read from the store (zeros).
    ASSERT_TRUE(h.ok());
    EXPECT_TRUE(PageIsZero(h->data()));
  }
  EXPECT_TRUE(CachedPageIs(cache, 2, 1));
  EXPECT_TRUE(CachedPageIs(cache, 5, 9));  // Written back at eviction, now read back.
  const auto stats = cache.stats();
  EXPECT_EQ(stats.zero_pages, 2u);  // Pages 5 and 6 (at first).
  EXPECT_EQ(stats.buffer_allocations, 1u);
  EXPECT_EQ(store.reads(), 3u);  // Pages 1, 2 and 5 (after it was written).
}

}  // namespace
}  // namespace octoscope::paging
