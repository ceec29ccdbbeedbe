// Tests of PagePrefetcher: asynchronous loads that a render thread asks for without waiting.
#include "paging/page_prefetcher.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <set>
#include <shared_mutex>
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
using testing::FillPage;
using testing::Gate;
using testing::PageBytes;
using testing::PageIs;
using testing::PageIsZero;
using testing::WaitUntil;
using testing::WritePage;
using Result = PrefetchRequestResult;

constexpr uint64_t kPage = 256;

// A store holding FillPage(p, p + 1) for pages [0, pages).
void FillStore(MemoryPageStore& store, uint64_t pages) {
  for (uint64_t p = 0; p < pages; ++p) ASSERT_TRUE(store.Write(p, PageBytes(kPage, p, p + 1)).ok());
}

// Collects completions until `count` arrived (or a generous time passed: a failing test).
std::vector<PrefetchCompletion> Collect(PagePrefetcher& prefetcher, size_t count) {
  std::vector<PrefetchCompletion> all;
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (all.size() < count && std::chrono::steady_clock::now() < deadline) {
    if (prefetcher.WaitForCompletion(100ms)) {
      for (auto& c : prefetcher.TakeCompletions()) all.push_back(std::move(c));
    }
  }
  return all;
}

// Requests `page`, waits for its completion and checks that it succeeded and left the page
// resident.
::testing::AssertionResult PrefetchSucceeds(PagePrefetcher& prefetcher, PageCache& cache,
                                            uint64_t page) {
  const Result result = prefetcher.Request(&cache, page);
  if (result != Result::kQueued) {
    return ::testing::AssertionFailure() << "request: " << static_cast<int>(result);
  }
  const auto done = Collect(prefetcher, 1);
  if (done.size() != 1) return ::testing::AssertionFailure() << done.size() << " completions";
  if (done[0].page != page || !done[0].status.ok()) {
    return ::testing::AssertionFailure()
           << "page " << done[0].page << ": " << done[0].status.ToString();
  }
  if (!cache.IsResident(page)) return ::testing::AssertionFailure() << "not resident";
  return ::testing::AssertionSuccess();
}

TEST(PagePrefetcherTest, RequestedPagesBecomeTryPinnableAndStayUnpinned) {
  MemoryPageStore store(kPage);
  FillStore(store, 10);
  PageCache cache(&store, 16 * kPage);
  PagePrefetcher prefetcher;
  for (uint64_t p = 0; p < 10; ++p) EXPECT_EQ(prefetcher.Request(&cache, p), Result::kQueued);
  const auto done = Collect(prefetcher, 10);
  ASSERT_EQ(done.size(), 10u);
  std::set<uint64_t> pages;
  for (const auto& c : done) {
    EXPECT_EQ(c.cache, &cache);
    EXPECT_TRUE(c.status.ok()) << c.status.ToString();
    pages.insert(c.page);
  }
  EXPECT_EQ(pages.size(), 10u);
  EXPECT_EQ(cache.stats().pinned_pages, 0u);
  for (uint64_t p = 0; p < 10; ++p) {
    auto h = cache.TryPin(p);
    ASSERT_TRUE(h.has_value()) << p;
    EXPECT_TRUE(PageIs(h->data(), p, p + 1));
  }
  // A resident page is not requested at all.
  EXPECT_EQ(prefetcher.Request(&cache, 3), Result::kResident);
  EXPECT_FALSE(prefetcher.WaitForCompletion(20ms));
  const auto stats = prefetcher.stats();
  EXPECT_EQ(stats.accepted, 10u);
  EXPECT_EQ(stats.loaded, 10u);
  EXPECT_EQ(stats.resident, 1u);
  EXPECT_EQ(stats.queued + stats.in_flight, 0u);
  EXPECT_EQ(store.reads(), 10u);
}

TEST(PagePrefetcherTest, LoadedPagesAreMostRecentlyUsed) {
  MemoryPageStore store(kPage);
  FillStore(store, 8);
  PageCache cache(&store, 3 * kPage);
  for (uint64_t p : {0, 1, 2}) ASSERT_TRUE(cache.Pin(p).ok());  // LRU: 0 1 2.
  PagePrefetcher prefetcher;
  ASSERT_TRUE(PrefetchSucceeds(prefetcher, cache, 5));  // Evicts 0: 1 2 5.
  ASSERT_TRUE(cache.Pin(6).ok());                       // Evicts 1, not the prefetched page.
  EXPECT_TRUE(cache.IsResident(5));
  EXPECT_FALSE(cache.IsResident(0));
  EXPECT_FALSE(cache.IsResident(1));
}

// A store holding FillStore(kGatedPages) whose reads wait at gate_ until the test opens it, and a
// cache over it that holds all those pages.
class GatedStorePrefetchTest : public ::testing::Test {
 protected:
  static constexpr uint64_t kGatedPages = 16;
  GatedStorePrefetchTest() {
    FillStore(inner_, kGatedPages);
    store_.SetBeforeRead([this](uint64_t) { gate_.Pass(); });
  }

  MemoryPageStore inner_{kPage};
  FaultInjectingPageStore store_{&inner_};
  Gate gate_;
  PageCache cache_{&store_, kGatedPages* kPage};
};

TEST_F(GatedStorePrefetchTest, DuplicateRequestsShareOneLoad) {
  PagePrefetcher prefetcher({.io_threads = 1});
  EXPECT_EQ(prefetcher.Request(&cache_, 2), Result::kQueued);
  gate_.AwaitArrivals(1);  // In flight now.
  EXPECT_EQ(prefetcher.Request(&cache_, 2), Result::kDuplicate);
  EXPECT_EQ(prefetcher.Request(&cache_, 3), Result::kQueued);
  EXPECT_EQ(prefetcher.Request(&cache_, 3), Result::kDuplicate);  // Queued.
  gate_.Open();
  const auto done = Collect(prefetcher, 2);
  ASSERT_EQ(done.size(), 2u);
  EXPECT_FALSE(prefetcher.WaitForCompletion(20ms));  // Exactly one completion per page.
  EXPECT_EQ(inner_.read_count(2), 1u);
  EXPECT_EQ(inner_.read_count(3), 1u);
  EXPECT_EQ(prefetcher.stats().duplicates, 2u);
}

TEST(PagePrefetcherTest, AFailedReadIsReportedOnceAndNotRetriedWhileHeld) {
  MemoryPageStore inner(kPage);
  FillStore(inner, 8);
  FaultInjectingPageStore store(&inner);
  store.FailReadsOfPage(4);
  PageCache cache(&store, 8 * kPage);
  PagePrefetcher prefetcher({.failure_hold = 200ms});
  ASSERT_EQ(prefetcher.Request(&cache, 4), Result::kQueued);
  ASSERT_EQ(prefetcher.Request(&cache, 5), Result::kQueued);
  auto done = Collect(prefetcher, 2);
  ASSERT_EQ(done.size(), 2u);
  std::map<uint64_t, Status> by_page;
  for (auto& c : done) by_page[c.page] = c.status;
  EXPECT_EQ(by_page[4].code(), StatusCode::kIoError);
  EXPECT_NE(by_page[4].message().find("page 4"), std::string::npos) << by_page[4].message();
  EXPECT_TRUE(by_page[5].ok());
  // A render loop asking again every frame does not hammer the bad page.
  const uint64_t reads = store.reads();
  for (int i = 0; i < 20; ++i) EXPECT_EQ(prefetcher.Request(&cache, 4), Result::kRecentlyFailed);
  EXPECT_EQ(store.reads(), reads);
  EXPECT_EQ(prefetcher.stats().failed, 1u);
  // After the hold it may be tried again; the store recovered meanwhile.
  store.FailReadsOfPage(std::nullopt);
  std::this_thread::sleep_for(250ms);
  EXPECT_TRUE(PrefetchSucceeds(prefetcher, cache, 4));
}

TEST(PagePrefetcherTest, AVictimsFailedWriteBackIsReportedButTheRequestedPageIsNotHeld) {
  MemoryPageStore inner(kPage);
  FillStore(inner, 4);
  FaultInjectingPageStore store(&inner);
  PageCache cache(&store, kPage);  // One page: loading page 1 must evict page 0.
  WritePage(cache, 0, 9);
  store.FailWritesOfPage(0);
  PagePrefetcher prefetcher;
  ASSERT_EQ(prefetcher.Request(&cache, 1), Result::kQueued);
  auto done = Collect(prefetcher, 1);
  ASSERT_EQ(done.size(), 1u);
  EXPECT_EQ(done[0].status.code(), StatusCode::kIoError);
  EXPECT_NE(done[0].status.message().find("page 0"), std::string::npos) << done[0].status.message();
  EXPECT_TRUE(testing::CachedPageIs(cache, 0, 9));  // The victim kept its data.
  // Page 1 itself is fine: asking again is allowed and works once the store writes again.
  store.FailWritesOfPage(std::nullopt);
  EXPECT_TRUE(PrefetchSucceeds(prefetcher, cache, 1));
  EXPECT_TRUE(PageIs(*inner.PageContents(0), 0, 9));
}

TEST(PagePrefetcherTest, ACacheFullOfPinnedPagesGivesNoRoomInsteadOfBlockingTheIoThread) {
  MemoryPageStore store(kPage);
  FillStore(store, 8);
  PageCache cache(&store, 2 * kPage);
  auto a = cache.Pin(0);
  auto b = cache.Pin(1);
  ASSERT_TRUE(a.ok() && b.ok());
  PagePrefetcher prefetcher({.io_threads = 1, .room_timeout = 30ms});
  ASSERT_EQ(prefetcher.Request(&cache, 5), Result::kQueued);
  ASSERT_EQ(prefetcher.Request(&cache, 6), Result::kQueued);
  auto done = Collect(prefetcher, 2);  // The one I/O thread got through both.
  ASSERT_EQ(done.size(), 2u);
  for (const auto& c : done) {
    EXPECT_EQ(c.status.code(), StatusCode::kResourceExhausted) << c.status.ToString();
  }
  EXPECT_EQ(prefetcher.stats().no_room, 2u);
  // Transient: not remembered as a failure. With room, the same request succeeds.
  b->Reset();
  EXPECT_TRUE(PrefetchSucceeds(prefetcher, cache, 5));
}

TEST_F(GatedStorePrefetchTest, CancelAllDropsQueuedRequestsAndSuppressesTheLoadInFlight) {
  PagePrefetcher prefetcher({.io_threads = 1});
  for (uint64_t p = 0; p < 10; ++p) ASSERT_EQ(prefetcher.Request(&cache_, p), Result::kQueued);
  gate_.AwaitArrivals(1);  // Page 0 in flight, 1..9 queued.
  EXPECT_EQ(prefetcher.CancelAll(&cache_), 10u);
  EXPECT_EQ(prefetcher.stats().queued, 0u);
  gate_.Open();
  ASSERT_TRUE(WaitUntil([&] { return prefetcher.stats().in_flight == 0; }));
  EXPECT_FALSE(prefetcher.WaitForCompletion(20ms));
  EXPECT_EQ(inner_.read_count(0), 1u);
  for (uint64_t p = 1; p < 10; ++p) EXPECT_EQ(inner_.read_count(p), 0u) << p;
  EXPECT_EQ(prefetcher.stats().cancelled, 10u);
  // The load in flight still made its page resident (harmless); new requests work.
  EXPECT_TRUE(cache_.IsResident(0));
  EXPECT_TRUE(PrefetchSucceeds(prefetcher, cache_, 12));
}

TEST_F(GatedStorePrefetchTest, RequestingACancelledPageInFlightAgainRevivesItsCompletion) {
  PagePrefetcher prefetcher({.io_threads = 1});
  ASSERT_EQ(prefetcher.Request(&cache_, 1), Result::kQueued);
  gate_.AwaitArrivals(1);
  EXPECT_EQ(prefetcher.CancelAll(), 1u);
  EXPECT_EQ(prefetcher.Request(&cache_, 1), Result::kDuplicate);  // Same load, wanted again.
  gate_.Open();
  auto done = Collect(prefetcher, 1);
  ASSERT_EQ(done.size(), 1u);
  EXPECT_EQ(done[0].page, 1u);
  EXPECT_TRUE(done[0].status.ok());
  EXPECT_EQ(inner_.read_count(1), 1u);
}

TEST(PagePrefetcherTest, CancelAllOfOneCacheLeavesTheOthersAndDetachWaitsForItsLoads) {
  MemoryPageStore inner_a(kPage), inner_b(kPage);
  FillStore(inner_a, 8);
  FillStore(inner_b, 8);
  FaultInjectingPageStore store_a(&inner_a);
  Gate gate;
  store_a.SetBeforeRead([&](uint64_t) { gate.Pass(); });
  auto cache_a = std::make_unique<PageCache>(&store_a, 8 * kPage);
  PageCache cache_b(&inner_b, 8 * kPage);
  PagePrefetcher prefetcher({.io_threads = 1});
  ASSERT_EQ(prefetcher.Request(cache_a.get(), 0), Result::kQueued);
  gate.AwaitArrivals(1);  // The only I/O thread is busy with cache A.
  for (uint64_t p = 1; p < 4; ++p) ASSERT_EQ(prefetcher.Request(cache_a.get(), p), Result::kQueued);
  for (uint64_t p = 0; p < 4; ++p) ASSERT_EQ(prefetcher.Request(&cache_b, p), Result::kQueued);
  std::atomic<bool> detached{false};
  auto detacher = std::async(std::launch::async, [&] {
    prefetcher.Detach(cache_a.get());  // Waits for the load of A's page 0.
    detached = true;
    cache_a.reset();  // Allowed now.
  });
  std::this_thread::sleep_for(30ms);
  EXPECT_FALSE(detached.load());
  gate.Open();
  detacher.get();
  auto done = Collect(prefetcher, 4);
  ASSERT_EQ(done.size(), 4u);
  for (const auto& c : done) {
    EXPECT_EQ(c.cache, &cache_b);
    EXPECT_TRUE(c.status.ok());
  }
  for (uint64_t p = 1; p < 4; ++p) EXPECT_EQ(inner_a.read_count(p), 0u);
  EXPECT_FALSE(prefetcher.WaitForCompletion(20ms));
}

TEST(PagePrefetcherTest, TheQueueIsBoundedByOutstandingRequestsAndCompletions) {
  MemoryPageStore store(kPage);
  FillStore(store, 16);
  PageCache cache(&store, 16 * kPage);
  PagePrefetcher prefetcher({.max_outstanding = 4});
  for (uint64_t p = 0; p < 4; ++p) ASSERT_EQ(prefetcher.Request(&cache, p), Result::kQueued);
  EXPECT_EQ(prefetcher.Request(&cache, 9), Result::kQueueFull);
  ASSERT_TRUE(WaitUntil([&] { return prefetcher.stats().loaded == 4; }));
  // Loaded but not yet taken: still outstanding (no report is ever dropped).
  EXPECT_EQ(prefetcher.Request(&cache, 9), Result::kQueueFull);
  EXPECT_EQ(prefetcher.TakeCompletions().size(), 4u);
  EXPECT_TRUE(PrefetchSucceeds(prefetcher, cache, 9));
}

TEST(PagePrefetcherTest, TheCallbackReceivesEveryCompletionOnAnIoThread) {
  MemoryPageStore inner(kPage);
  FillStore(inner, 32);
  FaultInjectingPageStore store(&inner);
  store.FailReadsOfPage(7);
  PageCache cache(&store, 64 * kPage);
  std::mutex mu;
  std::map<uint64_t, StatusCode> seen;
  std::atomic<bool> on_caller_thread{false};
  const auto caller = std::this_thread::get_id();
  {
    PagePrefetcher prefetcher({.io_threads = 3, .on_complete = [&](const PrefetchCompletion& c) {
                                 if (std::this_thread::get_id() == caller) on_caller_thread = true;
                                 std::lock_guard lock(mu);
                                 seen[c.page] = c.status.code();
                               }});
    for (uint64_t p = 0; p < 32; ++p) ASSERT_EQ(prefetcher.Request(&cache, p), Result::kQueued);
    ASSERT_TRUE(WaitUntil([&] {
      std::lock_guard lock(mu);
      return seen.size() == 32;
    }));
    EXPECT_FALSE(prefetcher.WaitForCompletion(10ms));  // Nothing is queued with a callback.
  }
  EXPECT_FALSE(on_caller_thread.load());
  for (uint64_t p = 0; p < 32; ++p) {
    EXPECT_EQ(seen[p], p == 7 ? StatusCode::kIoError : StatusCode::kOk) << p;
  }
}

TEST_F(GatedStorePrefetchTest, DestructionWithRequestsQueuedAndInFlightJoinsCleanly) {
  std::atomic<int> callbacks{0};
  auto prefetcher = std::make_unique<PagePrefetcher>(PagePrefetcherOptions{
      .io_threads = 2, .on_complete = [&](const PrefetchCompletion&) { ++callbacks; }});
  for (uint64_t p = 0; p < kGatedPages; ++p) {
    ASSERT_EQ(prefetcher->Request(&cache_, p), Result::kQueued);
  }
  gate_.AwaitArrivals(2);  // Both I/O threads are inside a read.
  auto destroyer = std::async(std::launch::async, [&] { prefetcher.reset(); });
  std::this_thread::sleep_for(20ms);
  gate_.Open();
  destroyer.get();
  EXPECT_EQ(callbacks.load(), 0);  // Nothing is delivered once destruction began.
  EXPECT_LE(store_.reads(), 2u);   // Queued requests were dropped, not served.
  EXPECT_EQ(cache_.stats().pinned_pages, 0u);
}

TEST(PagePrefetcherTest, RenderThreadPrefetchingWhileBuildersWriteSeesConsistentPages) {
  // Two datasets share one prefetcher; builder threads modify pages while a render thread
  // requests pages, waits for arrivals and reads what it can TryPin. The caller-side rule "one
  // writer per page at a time, no reader meanwhile" is kept with a shared_mutex per page. Every
  // page the render thread reads must be a whole version of that page (or never written).
  constexpr uint64_t kPages = 24;
  constexpr uint64_t kVersions = 40;
  MemoryPageStore store_a(kPage), store_b(kPage);
  PageCache cache_a(&store_a, 8 * kPage, PageCacheOptions{.write_behind = true});
  PageCache cache_b(&store_b, 6 * kPage);
  PageCache* caches[2] = {&cache_a, &cache_b};
  std::vector<std::shared_mutex> locks(2 * kPages);
  PagePrefetcher prefetcher({.io_threads = 2, .room_timeout = 50ms});
  std::atomic<bool> stop{false};
  std::atomic<int> bad{0};
  std::vector<std::thread> builders;
  for (int t = 0; t < 2; ++t) {
    builders.emplace_back([&, t] {
      // Thread t writes the pages p with p % 2 == t of both caches.
      for (uint64_t version = 1; version <= kVersions; ++version) {
        for (uint64_t p = static_cast<uint64_t>(t); p < kPages; p += 2) {
          for (int c = 0; c < 2; ++c) {
            auto h = caches[c]->Pin(p);
            if (!h.ok()) {
              ++bad;
              continue;
            }
            std::unique_lock lock(locks[c * kPages + p]);
            h->MarkDirty();
            FillPage(h->data(), p, version);
          }
        }
        std::this_thread::sleep_for(100us);  // Let the render thread interleave.
      }
    });
  }
  std::thread render([&] {
    std::mt19937 rng(3);
    // At least 200 rounds, however the threads are scheduled.
    for (int round = 0; round < 200 || !stop.load(); ++round) {
      for (int i = 0; i < 8; ++i) {
        const int c = static_cast<int>(rng() % 2);
        const uint64_t page = rng() % kPages;
        if (auto h = caches[c]->TryPin(page)) {
          std::shared_lock lock(locks[c * kPages + page]);
          const uint64_t version = testing::PageVersion(h->data());
          if (version == 0 ? !PageIsZero(h->data()) : !PageIs(h->data(), page, version)) ++bad;
        } else {
          const auto r = prefetcher.Request(caches[c], page);
          if (r == Result::kShutDown || r == Result::kRecentlyFailed) ++bad;
        }
      }
      prefetcher.WaitForCompletion(1ms);
      for (const auto& done : prefetcher.TakeCompletions()) {
        if (!done.status.ok() && done.status.code() != StatusCode::kResourceExhausted) ++bad;
      }
    }
  });
  for (auto& b : builders) b.join();
  stop = true;
  render.join();
  prefetcher.Detach(&cache_a);
  prefetcher.Detach(&cache_b);
  EXPECT_EQ(bad.load(), 0);
  for (PageCache* cache : caches) {
    ASSERT_TRUE(cache->Flush().ok());
    for (uint64_t p = 0; p < kPages; ++p) {
      EXPECT_TRUE(testing::CachedPageIs(*cache, p, kVersions)) << p;
    }
  }
  EXPECT_GT(prefetcher.stats().accepted, 0u);
}

}  // namespace
}  // namespace octoscope::paging
