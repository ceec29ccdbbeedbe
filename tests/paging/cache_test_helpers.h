// Test helpers for PageCache / PagePrefetcher tests: stamping and checking pages through a cache,
// polling for a condition that another thread brings about, a gate that holds store operations
// (from FaultInjectingPageStore hooks) until the test opens it, and a multi-threaded hammer that
// checks every page's contents against the last version written.
//
// Thread safety: the functions are as thread-safe as the cache they use; Gate is thread-safe.
#ifndef OCTOSCOPE_TESTS_PAGING_CACHE_TEST_HELPERS_H_
#define OCTOSCOPE_TESTS_PAGING_CACHE_TEST_HELPERS_H_

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <random>
#include <shared_mutex>
#include <thread>
#include <vector>

#include "paging/page_cache.h"
#include "paging/page_pattern.h"
#include "paging/page_store.h"

namespace octoscope::paging::testing {

// Pins `page`, stamps it with `version` (FillPage) and releases it.
inline void WritePage(PageCache& cache, uint64_t page, uint64_t version) {
  auto handle = cache.Pin(page);
  ASSERT_TRUE(handle.ok()) << handle.status().ToString();
  handle->MarkDirty();
  FillPage(handle->data(), page, version);
}

// Pins pages [first, first + count), marks each dirty and stamps it with `version`; returns the
// pins (release them in order to make that the LRU order).
inline std::vector<PageHandle> PinDirty(PageCache& cache, uint64_t first, uint64_t count,
                                        uint64_t version) {
  std::vector<PageHandle> held;
  for (uint64_t p = first; p < first + count; ++p) {
    auto h = cache.Pin(p);
    EXPECT_TRUE(h.ok()) << h.status().ToString();
    if (!h.ok()) continue;
    h->MarkDirty();
    FillPage(h->data(), p, version);
    held.push_back(std::move(h).value());
  }
  return held;
}

// Pins `page` and checks that it holds FillPage(page, version).
inline ::testing::AssertionResult CachedPageIs(PageCache& cache, uint64_t page, uint64_t version) {
  auto handle = cache.Pin(page);
  if (!handle.ok()) return ::testing::AssertionFailure() << handle.status().ToString();
  return PageIs(handle->data(), page, version);
}

// Resident and loaded (counts as a use: TryPin moves the page to the MRU end).
inline bool IsResident(PageCache& cache, uint64_t page) { return cache.TryPin(page).has_value(); }

// Polls `condition` until it holds or `timeout` passes (for effects of background threads; the
// timeout only bounds a failing test, no test asserts a time). Returns the last value.
inline bool WaitUntil(const std::function<bool()>& condition,
                      std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!condition()) {
    if (std::chrono::steady_clock::now() >= deadline) return condition();
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return true;
}

// Holds the threads that call Pass() until Open(); counts them.
class Gate {
 public:
  void Pass() {
    std::unique_lock lock(mu_);
    ++arrived_;
    cv_.notify_all();
    cv_.wait(lock, [this] { return open_; });
  }
  void Open() {
    std::lock_guard lock(mu_);
    open_ = true;
    cv_.notify_all();
  }
  // Waits until at least `n` threads have called Pass().
  void AwaitArrivals(int n) {
    std::unique_lock lock(mu_);
    cv_.wait(lock, [&] { return arrived_ >= n; });
  }
  int arrived() const {
    std::lock_guard lock(mu_);
    return arrived_;
  }

 private:
  mutable std::mutex mu_;
  std::condition_variable cv_;
  bool open_ = false;
  int arrived_ = 0;
};

// Many threads pin random pages, check that each page holds exactly the last version written to
// it, and write new versions; a render thread TryPins meanwhile. The caller-side rule "one writer
// per page at a time" is kept with a shared_mutex per page. At the end the store must hold the
// last version of every page. `background`, when set, is called over and over by one more thread
// while the workers run (e.g. to change the budget).
inline void Hammer(PageStore* store, PageCache& cache, uint64_t pages, int threads, int ops,
                   bool retry_errors, const std::function<void()>& background = nullptr) {
  std::vector<std::shared_mutex> locks(pages);
  std::vector<uint64_t> versions(pages, 0);  // Guarded by locks[page]; 0 = never written.
  std::atomic<int> bad{0};
  std::atomic<bool> stop{false};
  std::vector<std::thread> workers;
  for (int t = 0; t < threads; ++t) {
    workers.emplace_back([&, t] {
      std::mt19937 rng(1000 + t);
      for (int i = 0; i < ops; ++i) {
        const uint64_t page = rng() % pages;
        const bool write = rng() % 2 == 0;
        auto h = cache.Pin(page);
        if (!h.ok()) {
          if (!retry_errors || h.status().code() != StatusCode::kIoError) bad.fetch_add(1);
          continue;
        }
        if (write) {
          std::unique_lock lock(locks[page]);
          const uint64_t v = versions[page];
          if (v == 0 ? !PageIsZero(h->data()) : !PageIs(h->data(), page, v)) bad.fetch_add(1);
          h->MarkDirty();
          versions[page] = v + 1;
          FillPage(h->data(), page, v + 1);
        } else {
          std::shared_lock lock(locks[page]);
          const uint64_t v = versions[page];
          if (v == 0 ? !PageIsZero(h->data()) : !PageIs(h->data(), page, v)) bad.fetch_add(1);
        }
      }
    });
  }
  std::thread render([&] {
    std::mt19937 rng(7);
    while (!stop.load()) {
      const uint64_t page = rng() % pages;
      if (auto h = cache.TryPin(page)) {
        std::shared_lock lock(locks[page]);
        const uint64_t v = versions[page];
        if (v == 0 ? !PageIsZero(h->data()) : !PageIs(h->data(), page, v)) bad.fetch_add(1);
      }
    }
  });
  std::thread extra([&] {
    while (background && !stop.load()) background();
  });
  for (auto& w : workers) w.join();
  stop = true;
  render.join();
  extra.join();
  EXPECT_EQ(bad.load(), 0);

  // Everything reaches the store, even when some writes failed on the way.
  Status flushed = cache.Flush();
  for (int attempt = 0; attempt < 20 && !flushed.ok(); ++attempt) flushed = cache.Flush();
  ASSERT_TRUE(flushed.ok()) << flushed.ToString();
  std::vector<std::byte> buf(store->page_bytes());
  for (uint64_t page = 0; page < pages; ++page) {
    ASSERT_TRUE(store->Read(page, buf).ok());
    if (versions[page] == 0) {
      EXPECT_TRUE(PageIsZero(buf)) << page;
    } else {
      EXPECT_TRUE(PageIs(buf, page, versions[page])) << page;
    }
  }
  const auto stats = cache.stats();
  EXPECT_EQ(stats.pinned_pages, 0u);
  EXPECT_EQ(stats.dirty_pages, 0u);
}

}  // namespace octoscope::paging::testing

#endif  // OCTOSCOPE_TESTS_PAGING_CACHE_TEST_HELPERS_H_
