// Tests of PageCache: LRU order, the hard budget, pinning, write-back, fault handling and
// concurrency. Pages carry their id and a version (page_pattern.h), so every read checks which
// write it sees.
#include "paging/page_cache.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <future>
#include <random>
#include <shared_mutex>
#include <string>
#include <thread>
#include <vector>

#include "paging/cache_test_helpers.h"
#include "paging/fault_injecting_page_store.h"
#include "paging/file_page_store.h"
#include "paging/memory_page_store.h"
#include "paging/page_pattern.h"

namespace octoscope::paging {
namespace {

using namespace std::chrono_literals;
using testing::CachedPageIs;
using testing::FillPage;
using testing::Hammer;
using testing::IsResident;
using testing::PageBytes;
using testing::PageIs;
using testing::PageIsZero;
using testing::WritePage;

constexpr uint64_t kPage = 256;

// --- Basics --------------------------------------------------------------------------------------

TEST(PageCacheTest, MissLoadsThenHitsAndStatsCount) {
  MemoryPageStore store(kPage);
  ASSERT_TRUE(store.Write(2, PageBytes(kPage, 2, 7)).ok());
  PageCache cache(&store, 4 * kPage);
  EXPECT_EQ(cache.capacity_pages(), 4u);
  EXPECT_EQ(cache.page_bytes(), kPage);
  {
    auto h = cache.Pin(2);
    ASSERT_TRUE(h.ok());
    EXPECT_EQ(h->page(), 2u);
    EXPECT_EQ(h->data().size(), kPage);
    EXPECT_TRUE(PageIs(h->data(), 2, 7));
    auto again = cache.Pin(2);  // A second pin of a pinned page: same bytes.
    ASSERT_TRUE(again.ok());
    EXPECT_EQ(again->data().data(), h->data().data());
    EXPECT_EQ(cache.stats().pinned_pages, 1u);
  }
  auto zero = cache.Pin(9);  // Never written (beyond page_count()): zeros, without a read.
  ASSERT_TRUE(zero.ok());
  EXPECT_TRUE(PageIsZero(zero->data()));
  zero->Reset();
  EXPECT_FALSE(zero->valid());

  const auto stats = cache.stats();
  EXPECT_EQ(stats.misses, 2u);
  EXPECT_EQ(stats.hits, 1u);
  EXPECT_EQ(stats.bytes_read, kPage);
  EXPECT_EQ(stats.zero_pages, 1u);
  EXPECT_EQ(stats.buffer_allocations, 2u);
  EXPECT_EQ(stats.resident_bytes, 2 * kPage);
  EXPECT_EQ(stats.pinned_pages, 0u);
  EXPECT_EQ(stats.dirty_pages, 0u);
  EXPECT_EQ(stats.evictions, 0u);
  EXPECT_EQ(store.reads(), 1u);
  EXPECT_EQ(store.read_count(9), 0u);
}

TEST(PageCacheTest, HandlesMoveAndUnpinExactlyOnce) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 2 * kPage);
  auto r = cache.Pin(1);
  ASSERT_TRUE(r.ok());
  PageHandle a = std::move(r).value();
  PageHandle b(std::move(a));
  EXPECT_FALSE(a.valid());  // NOLINT(bugprone-use-after-move): moved-from is empty by contract.
  EXPECT_TRUE(b.valid());
  PageHandle c;
  c = std::move(b);
  EXPECT_EQ(cache.stats().pinned_pages, 1u);
  auto other = cache.Pin(0);
  ASSERT_TRUE(other.ok());
  c = std::move(other).value();  // Releases page 1, takes over page 0.
  EXPECT_EQ(c.page(), 0u);
  EXPECT_EQ(cache.stats().pinned_pages, 1u);
  c.Reset();
  c.Reset();  // Idempotent.
  EXPECT_EQ(cache.stats().pinned_pages, 0u);
}

// --- LRU and budget ------------------------------------------------------------------------------

TEST(PageCacheTest, EvictsLeastRecentlyUsedPage) {
  MemoryPageStore store(kPage);
  for (uint64_t p = 0; p < 6; ++p) ASSERT_TRUE(store.Write(p, PageBytes(kPage, p, 1)).ok());
  PageCache cache(&store, 3 * kPage);
  for (uint64_t p : {0, 1, 2}) ASSERT_TRUE(cache.Pin(p).ok());  // LRU order: 0 1 2.
  ASSERT_TRUE(cache.Pin(0).ok());                               // Now: 1 2 0.
  ASSERT_TRUE(cache.Pin(3).ok());                               // Evicts 1 -> 2 0 3.
  EXPECT_FALSE(IsResident(cache, 1));
  ASSERT_TRUE(cache.Pin(4).ok());  // Evicts 2 -> 0 3 4.
  EXPECT_FALSE(IsResident(cache, 2));
  EXPECT_TRUE(IsResident(cache, 0));  // TryPin counts as a use: 3 4 0.
  ASSERT_TRUE(cache.Pin(5).ok());     // Evicts 3.
  EXPECT_FALSE(IsResident(cache, 3));
  EXPECT_TRUE(IsResident(cache, 4));
  EXPECT_TRUE(IsResident(cache, 0));
  EXPECT_TRUE(IsResident(cache, 5));
  EXPECT_EQ(cache.stats().evictions, 3u);
  EXPECT_EQ(store.read_count(0), 1u);  // Page 0 was never reloaded.
}

TEST(PageCacheTest, BudgetIsNeverExceeded) {
  MemoryPageStore store(kPage);
  // 4.5 pages of budget hold 4 pages.
  PageCache cache(&store, 4 * kPage + kPage / 2);
  EXPECT_EQ(cache.capacity_pages(), 4u);
  std::mt19937 rng(42);
  std::vector<PageHandle> held;
  for (int i = 0; i < 2000; ++i) {
    const uint64_t page = rng() % 40;
    auto h = cache.Pin(page);
    ASSERT_TRUE(h.ok()) << h.status().ToString();
    if (rng() % 3 == 0) {
      h->MarkDirty();
      FillPage(h->data(), page, i);
    }
    // Keep up to 3 pins alive at once so eviction works around pinned pages.
    held.push_back(std::move(h).value());
    if (held.size() > 3) held.erase(held.begin() + static_cast<ptrdiff_t>(rng() % held.size()));
    const auto stats = cache.stats();
    ASSERT_LE(stats.resident_bytes, cache.budget_bytes());
    ASSERT_EQ(stats.resident_bytes % kPage, 0u);
  }
  held.clear();
  const auto stats = cache.stats();
  EXPECT_EQ(stats.peak_resident_bytes, 4 * kPage);  // Reached, never passed.
  EXPECT_GT(stats.evictions, 100u);
}

TEST(PageCacheTest, BudgetBelowOnePageFailsCleanly) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, kPage - 1);
  EXPECT_EQ(cache.capacity_pages(), 0u);
  auto h = cache.Pin(0);
  ASSERT_FALSE(h.ok());
  EXPECT_EQ(h.status().code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(store.reads(), 0u);
  EXPECT_EQ(cache.stats().peak_resident_bytes, 0u);
}

TEST(PageCacheTest, PinnedPagesSurvivePressure) {
  MemoryPageStore store(kPage);
  ASSERT_TRUE(store.Write(100, PageBytes(kPage, 100, 0)).ok());
  PageCache cache(&store, 3 * kPage);
  auto pinned = cache.Pin(100);
  ASSERT_TRUE(pinned.ok());
  pinned->MarkDirty();
  FillPage(pinned->data(), 100, 1);
  std::byte* const address = pinned->data().data();
  for (uint64_t p = 0; p < 50; ++p) WritePage(cache, p, p + 1);
  // Still the same buffer and bytes, never written back or reloaded.
  EXPECT_EQ(pinned->data().data(), address);
  EXPECT_TRUE(PageIs(pinned->data(), 100, 1));
  EXPECT_EQ(store.write_count(100), 1u);  // Only the setup's write.
  EXPECT_EQ(store.read_count(100), 1u);
  EXPECT_LE(cache.stats().peak_resident_bytes, 3 * kPage);
  for (uint64_t p = 0; p < 50; ++p) EXPECT_TRUE(CachedPageIs(cache, p, p + 1)) << p;
}

// --- Blocking when everything is pinned ----------------------------------------------------------

TEST(PageCacheTest, PinBlocksUntilAPageIsUnpinned) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 2 * kPage);
  auto a = cache.Pin(0);
  auto b = cache.Pin(1);
  ASSERT_TRUE(a.ok() && b.ok());
  b->MarkDirty();
  FillPage(b->data(), 1, 3);
  std::atomic<bool> returned{false};
  auto waiter = std::async(std::launch::async, [&] {
    auto h = cache.Pin(2);
    returned = true;
    return h.ok() ? Status::Ok() : h.status();
  });
  // The waiter cannot finish while both pages are pinned (if it has not started yet, the check
  // holds trivially).
  std::this_thread::sleep_for(50ms);
  EXPECT_FALSE(returned.load());
  b->Reset();  // Frees page 1: it is written back and evicted, and the waiter proceeds.
  EXPECT_TRUE(waiter.get().ok());
  EXPECT_TRUE(returned.load());
  EXPECT_FALSE(IsResident(cache, 1));
  EXPECT_TRUE(IsResident(cache, 0));
  EXPECT_EQ(store.write_count(1), 1u);
  EXPECT_TRUE(PageIs(*store.PageContents(1), 1, 3));
  EXPECT_LE(cache.stats().peak_resident_bytes, 2 * kPage);
}

TEST(PageCacheTest, PinGivesUpWithResourceExhaustedAfterTheTimeout) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, kPage, 30ms);
  auto a = cache.Pin(0);
  ASSERT_TRUE(a.ok());
  auto b = cache.Pin(1);
  ASSERT_FALSE(b.ok());
  EXPECT_EQ(b.status().code(), StatusCode::kResourceExhausted);
  EXPECT_NE(b.status().message().find("pinned"), std::string::npos) << b.status().message();
  EXPECT_EQ(store.read_count(1), 0u);
  a->Reset();
  EXPECT_TRUE(cache.Pin(1).ok());  // Works again once there is room.
}

// --- TryPin --------------------------------------------------------------------------------------

TEST(PageCacheTest, TryPinNeverLoadsAndNeverWaitsForALoad) {
  MemoryPageStore inner(kPage);
  ASSERT_TRUE(inner.Write(3, PageBytes(kPage, 3, 1)).ok());
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, 2 * kPage);
  EXPECT_FALSE(cache.TryPin(3).has_value());
  EXPECT_EQ(store.reads(), 0u);
  EXPECT_EQ(cache.stats().misses, 0u);
  EXPECT_EQ(cache.stats().resident_bytes, 0u);

  // While page 3 is being loaded, TryPin must not wait for it.
  std::promise<void> load_started, release_load;
  std::shared_future<void> release = release_load.get_future().share();
  store.SetBeforeRead([&](uint64_t) {
    load_started.set_value();
    release.wait();
  });
  auto loader = std::async(std::launch::async, [&] { return cache.Pin(3).ok(); });
  load_started.get_future().wait();
  EXPECT_FALSE(cache.TryPin(3).has_value());
  release_load.set_value();
  EXPECT_TRUE(loader.get());
  store.SetBeforeRead(nullptr);

  auto h = cache.TryPin(3);
  ASSERT_TRUE(h.has_value());
  EXPECT_TRUE(PageIs(h->data(), 3, 1));
  EXPECT_EQ(store.reads(), 1u);
}

// --- Concurrent loads of one page ----------------------------------------------------------------

TEST(PageCacheTest, ConcurrentPinsOfOneMissingPageLoadItOnce) {
  MemoryPageStore inner(kPage);
  ASSERT_TRUE(inner.Write(5, PageBytes(kPage, 5, 2)).ok());
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, 4 * kPage);
  std::promise<void> release_load;
  std::shared_future<void> release = release_load.get_future().share();
  store.SetBeforeRead([&](uint64_t) { release.wait(); });
  constexpr int kThreads = 8;
  std::vector<std::future<bool>> pins;
  for (int i = 0; i < kThreads; ++i) {
    pins.push_back(std::async(std::launch::async, [&] {
      auto h = cache.Pin(5);
      return h.ok() && PageIs(h->data(), 5, 2);
    }));
  }
  // Give the threads time to pile up on the one load (the assertions hold either way).
  std::this_thread::sleep_for(30ms);
  release_load.set_value();
  for (auto& f : pins) EXPECT_TRUE(f.get());
  EXPECT_EQ(store.reads(), 1u);
  EXPECT_EQ(inner.read_count(5), 1u);
  const auto stats = cache.stats();
  EXPECT_EQ(stats.misses, 1u);
  EXPECT_EQ(stats.hits, kThreads - 1u);
  EXPECT_EQ(stats.resident_bytes, kPage);
}

TEST(PageCacheTest, HitsProceedWhileAMissIsReading) {
  MemoryPageStore inner(kPage);
  ASSERT_TRUE(inner.Write(2, PageBytes(kPage, 2, 1)).ok());  // So that loading it reads.
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, 4 * kPage);
  ASSERT_TRUE(cache.Pin(1).ok());  // Resident.
  std::promise<void> load_started, release_load;
  std::shared_future<void> release = release_load.get_future().share();
  store.SetBeforeRead([&](uint64_t) {
    load_started.set_value();
    release.wait();
  });
  auto loader = std::async(std::launch::async, [&] { return cache.Pin(2).ok(); });
  load_started.get_future().wait();
  // The loader is blocked inside the store: a hit must still complete (else this deadlocks).
  EXPECT_TRUE(cache.Pin(1).ok());
  EXPECT_TRUE(cache.TryPin(1).has_value());
  EXPECT_TRUE(cache.stats().resident_bytes == 2 * kPage);  // Loading page counts already.
  release_load.set_value();
  EXPECT_TRUE(loader.get());
}

// --- Write-back ----------------------------------------------------------------------------------

TEST(PageCacheTest, DirtyPagesAreWrittenBackExactlyOnceAndCleanPagesNever) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 3 * kPage);
  // Even pages dirty, odd pages only read.
  for (uint64_t p = 0; p < 20; ++p) {
    if (p % 2 == 0) {
      WritePage(cache, p, 10 + p);
    } else {
      ASSERT_TRUE(cache.Pin(p).ok());
    }
  }
  // Pages 17, 18, 19 are still resident; among them only 18 is dirty.
  EXPECT_EQ(cache.stats().dirty_pages, 1u);
  for (uint64_t p = 0; p < 20; ++p) {
    const uint64_t expected = (p % 2 == 0 && p != 18) ? 1 : 0;
    EXPECT_EQ(store.write_count(p), expected) << "page " << p;
  }
  ASSERT_TRUE(cache.Flush().ok());
  EXPECT_EQ(store.write_count(18), 1u);
  EXPECT_EQ(store.syncs(), 1u);
  ASSERT_TRUE(cache.Flush().ok());  // Nothing dirty: writes nothing, still syncs.
  EXPECT_EQ(store.writes(), 10u);
  EXPECT_EQ(store.syncs(), 2u);
  const auto stats = cache.stats();
  EXPECT_EQ(stats.writebacks, 10u);
  EXPECT_EQ(stats.bytes_written, 10 * kPage);
  EXPECT_EQ(stats.dirty_pages, 0u);
  for (uint64_t p = 0; p < 20; p += 2) EXPECT_TRUE(PageIs(*store.PageContents(p), p, 10 + p));
  // A clean re-read and eviction of a written page does not write it again.
  for (uint64_t p = 0; p < 20; ++p) ASSERT_TRUE(cache.Pin(p).ok());
  EXPECT_EQ(store.writes(), 10u);
}

TEST(PageCacheTest, DataRoundTripsThroughEviction) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 3 * kPage);
  for (int round = 1; round <= 3; ++round) {
    for (uint64_t p = 0; p < 25; ++p) WritePage(cache, p, round * 100 + p);
    for (uint64_t p = 0; p < 25; ++p) {
      ASSERT_TRUE(CachedPageIs(cache, (p * 7) % 25, round * 100 + (p * 7) % 25));
    }
  }
  EXPECT_LE(cache.stats().peak_resident_bytes, 3 * kPage);
}

TEST(PageCacheTest, DestructorWritesBackDirtyPages) {
  MemoryPageStore store(kPage);
  {
    PageCache cache(&store, 4 * kPage);
    WritePage(cache, 0, 1);
    WritePage(cache, 3, 2);
    EXPECT_EQ(store.writes(), 0u);
  }
  ASSERT_TRUE(store.PageContents(0).has_value() && store.PageContents(3).has_value());
  EXPECT_TRUE(PageIs(*store.PageContents(0), 0, 1));
  EXPECT_TRUE(PageIs(*store.PageContents(3), 3, 2));
}

TEST(PageCacheTest, FlushWaitsForAHandleThatMarkedThePageDirty) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 4 * kPage);
  auto h = cache.Pin(0);
  ASSERT_TRUE(h.ok());
  h->MarkDirty();
  FillPage(h->data(), 0, 1);
  auto flusher = std::async(std::launch::async, [&] { return cache.Flush(); });
  std::this_thread::sleep_for(30ms);
  // The holder keeps modifying: Flush must not have read the page yet.
  FillPage(h->data(), 0, 2);
  h->Reset();
  EXPECT_TRUE(flusher.get().ok());
  EXPECT_EQ(store.write_count(0), 1u);
  EXPECT_TRUE(PageIs(*store.PageContents(0), 0, 2));
}

TEST(PageCacheTest, FlushByTheWritingThreadItselfTimesOutInsteadOfDeadlocking) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 4 * kPage, 30ms);
  WritePage(cache, 1, 1);
  auto h = cache.Pin(0);
  ASSERT_TRUE(h.ok());
  h->MarkDirty();
  FillPage(h->data(), 0, 1);
  Status s = cache.Flush();
  EXPECT_EQ(s.code(), StatusCode::kResourceExhausted);
  EXPECT_NE(s.message().find("page 0"), std::string::npos) << s.message();
  EXPECT_TRUE(PageIs(*store.PageContents(1), 1, 1));  // The other page was still written.
  h->Reset();
  EXPECT_TRUE(cache.Flush().ok());
  EXPECT_TRUE(PageIs(*store.PageContents(0), 0, 1));
}

TEST(PageCacheTest, ReadersMayHoldAPageWhileItIsWrittenBackButMarkDirtyWaits) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, 4 * kPage);
  WritePage(cache, 0, 1);
  auto reader = cache.Pin(0);  // A read-only pin.
  ASSERT_TRUE(reader.ok());

  std::promise<void> write_started, release_write;
  std::shared_future<void> release = release_write.get_future().share();
  store.SetBeforeWrite([&](uint64_t) {
    write_started.set_value();
    release.wait();
  });
  auto flusher = std::async(std::launch::async, [&] { return cache.Flush(); });
  write_started.get_future().wait();
  // Reading during the write-back is fine, and TryPin does not wait for it.
  EXPECT_TRUE(PageIs(reader->data(), 0, 1));
  EXPECT_TRUE(cache.TryPin(0).has_value());
  std::atomic<bool> marked{false};
  auto marker = std::async(std::launch::async, [&] {
    reader->MarkDirty();  // Must wait: the store is reading this buffer right now.
    marked = true;
    FillPage(reader->data(), 0, 2);
  });
  std::this_thread::sleep_for(30ms);
  EXPECT_FALSE(marked.load());
  release_write.set_value();
  EXPECT_TRUE(flusher.get().ok());
  marker.get();
  EXPECT_TRUE(marked.load());
  store.SetBeforeWrite(nullptr);
  EXPECT_TRUE(PageIs(*inner.PageContents(0), 0, 1));  // The write saw the old, whole page.
  EXPECT_EQ(cache.stats().dirty_pages, 1u);           // The new change is pending.
  reader->Reset();
  ASSERT_TRUE(cache.Flush().ok());
  EXPECT_TRUE(PageIs(*inner.PageContents(0), 0, 2));
}

// --- Faults --------------------------------------------------------------------------------------

TEST(PageCacheTest, FailedReadReturnsTheErrorAndCachesNothing) {
  MemoryPageStore inner(kPage);
  ASSERT_TRUE(inner.Write(3, PageBytes(kPage, 3, 4)).ok());
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, 2 * kPage);
  store.FailNthRead(1);
  auto h = cache.Pin(3);
  ASSERT_FALSE(h.ok());
  EXPECT_EQ(h.status().code(), StatusCode::kIoError);
  EXPECT_NE(h.status().message().find("page 3"), std::string::npos);
  auto stats = cache.stats();
  EXPECT_EQ(stats.resident_bytes, 0u);
  EXPECT_EQ(stats.pinned_pages, 0u);
  EXPECT_EQ(stats.failed_reads, 1u);
  EXPECT_EQ(stats.bytes_read, 0u);
  EXPECT_FALSE(cache.TryPin(3).has_value());
  // The next Pin reads again and succeeds.
  EXPECT_TRUE(CachedPageIs(cache, 3, 4));
  EXPECT_EQ(store.reads(), 2u);
}

TEST(PageCacheTest, FailedWriteBackKeepsThePageDirtyAndResidentAndRetriesLater) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, kPage);  // One page: every miss evicts.
  WritePage(cache, 0, 1);
  ASSERT_TRUE(cache.Flush().ok());
  WritePage(cache, 0, 2);  // Dirty again, store holds version 1.
  store.FailNthWrite(1);
  store.SetTornWriteBytes(kPage / 2);  // The failed write tears the stored page.

  auto h = cache.Pin(1);
  ASSERT_FALSE(h.ok());
  EXPECT_EQ(h.status().code(), StatusCode::kIoError);
  EXPECT_NE(h.status().message().find("page 0"), std::string::npos) << h.status().message();
  EXPECT_FALSE(PageIs(*inner.PageContents(0), 0, 2));  // Torn on "disk" …
  {
    auto kept = cache.TryPin(0);  // … but the whole page is still in RAM and still dirty.
    ASSERT_TRUE(kept.has_value());
    EXPECT_TRUE(PageIs(kept->data(), 0, 2));
  }
  auto stats = cache.stats();
  EXPECT_EQ(stats.dirty_pages, 1u);
  EXPECT_EQ(stats.failed_writes, 1u);
  EXPECT_EQ(stats.evictions, 0u);
  EXPECT_LE(stats.peak_resident_bytes, kPage);

  // The next Pin retries the write-back, which now succeeds.
  ASSERT_TRUE(cache.Pin(1).ok());
  EXPECT_TRUE(PageIs(*inner.PageContents(0), 0, 2));
  EXPECT_TRUE(CachedPageIs(cache, 0, 2));
}

TEST(PageCacheTest, FailedFlushKeepsPagesDirtyAndALaterFlushWritesThem) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, 4 * kPage);
  for (uint64_t p = 0; p < 4; ++p) WritePage(cache, p, p + 1);
  store.FailWritesOfPage(2);
  Status s = cache.Flush();
  EXPECT_EQ(s.code(), StatusCode::kIoError);
  EXPECT_NE(s.message().find("page 2"), std::string::npos) << s.message();
  EXPECT_EQ(cache.stats().dirty_pages, 1u);  // Only page 2 is left.
  EXPECT_FALSE(inner.PageContents(2).has_value());
  for (uint64_t p : {0, 1, 3}) EXPECT_TRUE(PageIs(*inner.PageContents(p), p, p + 1));

  store.FailWritesOfPage(std::nullopt);
  store.FailSync(true);
  EXPECT_FALSE(cache.Flush().ok());  // Sync errors are reported too.
  store.FailSync(false);
  EXPECT_TRUE(cache.Flush().ok());
  EXPECT_TRUE(PageIs(*inner.PageContents(2), 2, 3));
  EXPECT_EQ(inner.write_count(2), 1u);
  EXPECT_EQ(cache.stats().dirty_pages, 0u);
}

// --- File store end to end -----------------------------------------------------------------------

TEST(PageCacheTest, FileStoreRoundTripThroughCacheAndReopen) {
  const auto path = std::filesystem::path(::testing::TempDir()) /
                    ("octoscope_page_cache_" + std::to_string(::getpid()) + ".bin");
  {
    auto store = OpenFilePageStore(path, kPage, OpenMode::kCreateTruncate);
    ASSERT_TRUE(store.ok()) << store.status().ToString();
    PageCache cache(store->get(), 3 * kPage);
    for (uint64_t p = 0; p < 12; ++p) WritePage(cache, p * 3, p + 100);
    ASSERT_TRUE(cache.Flush().ok());
  }
  {
    auto store = OpenFilePageStore(path, kPage, OpenMode::kOpenExisting);
    ASSERT_TRUE(store.ok()) << store.status().ToString();
    EXPECT_EQ((*store)->page_count(), 34u);
    PageCache cache(store->get(), 2 * kPage);
    for (uint64_t p = 0; p < 12; ++p) EXPECT_TRUE(CachedPageIs(cache, p * 3, p + 100));
    auto hole = cache.Pin(4);
    ASSERT_TRUE(hole.ok());
    EXPECT_TRUE(PageIsZero(hole->data()));
  }
  std::filesystem::remove(path);
}

// --- Concurrency ---------------------------------------------------------------------------------

TEST(PageCacheTest, ManyThreadsHammeringRandomPagesSeeConsistentData) {
  MemoryPageStore store(kPage);
  PageCache cache(&store, 10 * kPage);
  Hammer(&store, cache, 48, 6, 3000, /*retry_errors=*/false);
  EXPECT_LE(cache.stats().peak_resident_bytes, cache.budget_bytes());
  EXPECT_GT(cache.stats().evictions, 0u);
  EXPECT_GT(cache.stats().writebacks, 0u);
}

TEST(PageCacheTest, ManyThreadsWithAFaultyStoreLoseNoData) {
  MemoryPageStore inner(kPage);
  FaultInjectingPageStore store(&inner);
  store.FailEveryNthWrite(5);
  store.SetTornWriteBytes(kPage / 3);
  PageCache cache(&store, 8 * kPage);
  Hammer(&store, cache, 40, 6, 2000, /*retry_errors=*/true);
  EXPECT_LE(cache.stats().peak_resident_bytes, cache.budget_bytes());
  EXPECT_GT(store.failed_writes(), 0u);
}

TEST(PageCacheTest, ThreadsPinningMoreThanTheBudgetWaitForEachOther) {
  // 4 threads each hold 2 pins at once with room for only 5 pages: they must take turns.
  MemoryPageStore store(kPage);
  PageCache cache(&store, 5 * kPage);
  std::atomic<int> bad{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < 300; ++i) {
        const uint64_t a = static_cast<uint64_t>(t * 100 + i % 7);  // Private pages: no sharing.
        auto ha = cache.Pin(a);
        if (!ha.ok()) {
          bad.fetch_add(1);
          continue;
        }
        auto hb = cache.Pin(a + 50);
        if (!hb.ok()) bad.fetch_add(1);
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(bad.load(), 0);
  EXPECT_LE(cache.stats().peak_resident_bytes, 5 * kPage);
}

}  // namespace
}  // namespace octoscope::paging
