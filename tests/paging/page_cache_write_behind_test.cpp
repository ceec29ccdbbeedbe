// Tests of PageCache write-behind (PageCacheOptions::write_behind): what it writes and when, the
// dirty protocol while it writes, failing and slow writes, and concurrent modification.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <set>
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
using testing::Gate;
using testing::Hammer;
using testing::PageIs;
using testing::PinDirty;
using testing::WaitUntil;
using testing::WritePage;

constexpr uint64_t kPage = 256;

PageCacheOptions WriteBehind(double high, double low) {
  PageCacheOptions options;
  options.write_behind = true;
  options.dirty_high_water = high;
  options.dirty_low_water = low;
  return options;
}

TEST(PageCacheWriteBehindTest, WritesTheOldestUnpinnedDirtyPagesDownToTheLowWaterMark) {
  MemoryPageStore store(kPage);
  // 8 pages: starts above 4 dirty pages, stops at 2.
  PageCache cache(&store, 8 * kPage, WriteBehind(0.5, 0.25));
  // Dirty six pages while they are pinned (the writer cannot touch them), then release them in
  // order 0..5: that is their LRU order.
  std::vector<PageHandle> held = PinDirty(cache, 0, 6, 1);
  EXPECT_EQ(store.writes(), 0u);  // All dirty pages are pinned.
  for (auto& h : held) h.Reset();
  ASSERT_TRUE(WaitUntil([&] { return cache.stats().dirty_pages <= 2; }));
  std::this_thread::sleep_for(20ms);  // It must stop there, not go on.
  const auto stats = cache.stats();
  EXPECT_EQ(stats.dirty_pages, 2u);
  EXPECT_EQ(stats.write_behind_writes, 4u);
  EXPECT_EQ(stats.writebacks, 4u);
  for (uint64_t p = 0; p < 4; ++p) {
    EXPECT_EQ(store.write_count(p), 1u) << p;
    EXPECT_TRUE(PageIs(*store.PageContents(p), p, 1)) << p;
  }
  EXPECT_EQ(store.write_count(4) + store.write_count(5), 0u);  // The two youngest stay dirty.
  // Written pages stay resident and clean: nothing was evicted or reloaded.
  EXPECT_EQ(stats.evictions, 0u);
  EXPECT_EQ(stats.resident_bytes, 6 * kPage);
  for (uint64_t p = 0; p < 6; ++p) EXPECT_TRUE(cache.IsResident(p));
  // Flush has only the rest to do.
  ASSERT_TRUE(cache.Flush().ok());
  EXPECT_EQ(store.writes(), 6u);
}

TEST(PageCacheWriteBehindTest, KeepsEvictionFromWaitingForWritesAndLeavesLittleForFlush) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  std::atomic<int> writes_on_this_thread{0};
  const auto main_thread = std::this_thread::get_id();
  store.SetBeforeWrite([&](uint64_t) {
    if (std::this_thread::get_id() == main_thread) ++writes_on_this_thread;
    std::this_thread::sleep_for(1ms);  // A slow disk.
  });
  PageCache cache(&store, 16 * kPage, WriteBehind(0.25, 0.125));
  for (uint64_t p = 0; p < 200; ++p) {
    WritePage(cache, p, 7);
    std::this_thread::sleep_for(2ms);  // "Computation" between pages: the writer keeps up.
  }
  // However the threads were scheduled, the writer eventually gets below the high water mark
  // (4 pages) and Flush then writes at most that many pages.
  ASSERT_TRUE(WaitUntil([&] { return cache.stats().dirty_pages <= 4; }));
  const uint64_t writes_before_flush = store.writes();
  ASSERT_TRUE(cache.Flush().ok());
  EXPECT_LE(store.writes() - writes_before_flush, 4u);
  const auto stats = cache.stats();
  EXPECT_GT(stats.write_behind_writes, 0u);
  // Most write-backs ran on the writer thread rather than in the Pins that evicted (the
  // exact share depends on scheduling, so only the majority is checked).
  EXPECT_LT(writes_on_this_thread.load(), 100) << stats.write_behind_writes;
  for (uint64_t p = 0; p < 200; ++p) EXPECT_TRUE(PageIs(*inner.PageContents(p), p, 7)) << p;
}

TEST(PageCacheWriteBehindTest, MarkDirtyWaitsForTheBackgroundWriteOfThatPage) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  Gate gate;
  store.SetBeforeWrite([&](uint64_t page) {
    if (page == 0) gate.Pass();
  });
  PageCache cache(&store, 4 * kPage, WriteBehind(0, 0));  // Writes every unpinned dirty page.
  WritePage(cache, 0, 1);
  gate.AwaitArrivals(1);          // The writer is writing page 0 now.
  auto handle = cache.TryPin(0);  // Pinning and reading during the write is fine.
  ASSERT_TRUE(handle.has_value());
  EXPECT_TRUE(PageIs(handle->data(), 0, 1));
  WritePage(cache, 1, 1);  // Other pages are not held up by the slow write.
  EXPECT_TRUE(CachedPageIs(cache, 1, 1));
  std::atomic<bool> marked{false};
  auto marker = std::async(std::launch::async, [&] {
    handle->MarkDirty();  // Must wait: the store is reading this buffer.
    marked = true;
    FillPage(handle->data(), 0, 2);
    handle->Reset();
  });
  std::this_thread::sleep_for(30ms);
  EXPECT_FALSE(marked.load());
  gate.Open();
  marker.get();
  EXPECT_TRUE(marked.load());
  // The background write saw the whole old page; the new version is written next.
  ASSERT_TRUE(WaitUntil([&] { return cache.stats().dirty_pages == 0; }));
  EXPECT_TRUE(PageIs(*inner.PageContents(0), 0, 2));
  EXPECT_EQ(inner.write_count(0), 2u);
  ASSERT_TRUE(cache.Flush().ok());
}

TEST(PageCacheWriteBehindTest, AFailedBackgroundWriteKeepsThePageAndIsReportedByTheNextFlush) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  store.FailWritesOfPage(1);
  store.SetTornWriteBytes(kPage / 2);
  PageCache cache(&store, 8 * kPage, WriteBehind(0, 0));
  for (uint64_t p = 0; p < 4; ++p) WritePage(cache, p, p + 1);
  // The others get written although page 1 keeps failing (it is retried behind them).
  ASSERT_TRUE(WaitUntil([&] {
    return inner.write_count(0) + inner.write_count(2) + inner.write_count(3) == 3 &&
           store.failed_writes() >= 2;
  }));
  auto stats = cache.stats();
  EXPECT_EQ(stats.dirty_pages, 1u);
  EXPECT_GE(stats.failed_writes, 2u);
  EXPECT_FALSE(PageIs(*inner.PageContents(1), 1, 2));  // Torn on "disk" …
  {
    auto kept = cache.TryPin(1);  // … whole and dirty in RAM.
    ASSERT_TRUE(kept.has_value());
    EXPECT_TRUE(PageIs(kept->data(), 1, 2));
  }
  store.FailWritesOfPage(std::nullopt);
  // Reported once, even though the page is written now (by Flush or by the writer's retry).
  Status status = cache.Flush();
  EXPECT_EQ(status.code(), StatusCode::kIoError);
  EXPECT_NE(status.message().find("write-behind"), std::string::npos) << status.message();
  EXPECT_NE(status.message().find("page 1"), std::string::npos) << status.message();
  EXPECT_TRUE(PageIs(*inner.PageContents(1), 1, 2));
  EXPECT_EQ(cache.stats().dirty_pages, 0u);
  EXPECT_TRUE(cache.Flush().ok());
  for (uint64_t p = 0; p < 4; ++p) EXPECT_TRUE(PageIs(*inner.PageContents(p), p, p + 1)) << p;
}

TEST(PageCacheWriteBehindTest, WritesAndDropsPagesAboveALoweredBudgetOnceUnpinned) {
  MemoryPageStore store(kPage);
  // High water 1: the writer is idle until the budget is lowered below the dirty pages.
  PageCache cache(&store, 4 * kPage, WriteBehind(1, 1));
  std::vector<PageHandle> held = PinDirty(cache, 0, 4, 3);
  ASSERT_TRUE(cache.SetBudget(kPage).ok());
  EXPECT_EQ(cache.stats().resident_bytes, 4 * kPage);
  held.clear();  // Dirty: Unpin does no I/O, the writer takes them.
  ASSERT_TRUE(WaitUntil([&] { return cache.stats().resident_bytes <= kPage; }));
  EXPECT_EQ(cache.stats().resident_bytes, kPage);
  EXPECT_GE(cache.stats().write_behind_writes, 3u);
  ASSERT_TRUE(cache.Flush().ok());
  for (uint64_t p = 0; p < 4; ++p) EXPECT_TRUE(PageIs(*store.PageContents(p), p, 3)) << p;
}

TEST(PageCacheWriteBehindTest, DestructorJoinsTheWriterWithAWriteInFlightAndLosesNothing) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  Gate gate;
  store.SetBeforeWrite([&](uint64_t) { gate.Pass(); });
  auto cache = std::make_unique<PageCache>(&store, 8 * kPage, WriteBehind(0, 0));
  for (uint64_t p = 0; p < 6; ++p) WritePage(*cache, p, 4);
  gate.AwaitArrivals(1);
  auto destroyer = std::async(std::launch::async, [&] { cache.reset(); });
  std::this_thread::sleep_for(20ms);
  gate.Open();
  destroyer.get();
  for (uint64_t p = 0; p < 6; ++p) {
    ASSERT_TRUE(inner.PageContents(p).has_value()) << p;
    EXPECT_TRUE(PageIs(*inner.PageContents(p), p, 4)) << p;
  }
}

TEST(PageCacheWriteBehindTest, ThreadsModifyingPagesWhileItWritesSeeAndStoreTheLastVersions) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 10 * kPage, WriteBehind(0.2, 0.1));
  Hammer(&store, cache, 48, 6, 3000, /*retry_errors=*/false);
  EXPECT_GT(cache.stats().write_behind_writes, 0u);
  EXPECT_LE(cache.stats().peak_resident_bytes, 10 * kPage);
}

TEST(PageCacheWriteBehindTest, ThreadsWithAFaultySlowStoreAndBudgetChangesLoseNoData) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  store.FailEveryNthWrite(4);
  store.SetTornWriteBytes(kPage / 3);
  store.SetBeforeWrite([](uint64_t) { std::this_thread::sleep_for(50us); });
  PageCache cache(&store, 10 * kPage, WriteBehind(0.3, 0.1));
  std::atomic<int> round{0};
  Hammer(&store, cache, 40, 4, 1500, /*retry_errors=*/true, [&] {
    // Budget changes race with the writer; failures are expected (the faulty store).
    (void)cache.SetBudget((8 + (round++ % 5)) * kPage);
    std::this_thread::sleep_for(1ms);
  });
  EXPECT_GT(store.failed_writes(), 0u);
  EXPECT_LE(cache.stats().peak_resident_bytes, 12 * kPage);
}

}  // namespace
}  // namespace octoscope::paging
