// PagePrefetcher: asynchronous page loads for threads that must never wait for the disk (the
// OpenCL render thread). It owns a small pool of I/O threads shared by any number of PageCaches
// (one per dataset): Request(cache, page) only queues; an I/O thread loads the page through
// PageCache::Prefetch, which leaves it resident, UNPINNED and most recently used, so the render
// thread's next TryPin finds it (unless memory pressure evicted it again meanwhile).
//
// Requests: de-duplicated per (cache, page) while queued or in flight; dropped at once when the
// page is already resident; refused when the prefetcher holds max_outstanding requests (queued +
// in flight + completions not yet taken); served first in, first out across all caches.
//
// Completions: every accepted request that is not cancelled ends in exactly one completion
// {cache, page, status}. status OK: the page was resident when the load returned.
// kResourceExhausted: no room appeared within room_timeout (every resident page pinned, or a
// budget below one page) — transient, the page may be requested again at once. Any other error
// (the store's read error, a victim's failed write-back): reported as is. A page whose READ failed
// is remembered for failure_hold: requests for it are refused (kRecentlyFailed) meanwhile, so a
// render loop that re-requests what it misses every frame does not retry a bad page forever.
// Completions go to options.on_complete (called on an I/O thread, without the prefetcher's lock)
// when set, else into a queue the caller drains with TakeCompletions(), waiting with
// WaitForCompletion(timeout) ("wake me when any requested page arrived").
//
// Cancellation: CancelAll(cache) / CancelAll() drop queued requests at once (no completion) and
// suppress the completions of loads already in flight — unless such a page is requested again
// before its load returns, which revives its completion. It never waits for I/O. Detach(cache)
// also waits until no I/O thread uses `cache` and forgets everything about it (its remembered
// failures): afterwards the cache may be destroyed.
//
// Never stuck: a load waits for room at most min(room_timeout, the cache's pin_timeout) and then
// completes with kResourceExhausted, so an I/O thread is never blocked forever by a cache full of
// pinned pages. The destructor drops queued requests, waits for the loads in flight (each bounded
// as above) and joins the threads; no completion is delivered once it has begun.
//
// Thread safety: all member functions are thread-safe. Request, CancelAll, TakeCompletions and
// stats never wait for I/O (they take the prefetcher's lock briefly; Request also the cache's, via
// PageCache::IsResident). on_complete must not call Detach or destroy the prefetcher, and must not
// throw (an exception from it is caught and dropped). Each cache passed to Request must stay alive
// until Detach(cache) returned (or the prefetcher is destroyed).
#ifndef OCTOSCOPE_PAGING_PAGE_PREFETCHER_H_
#define OCTOSCOPE_PAGING_PAGE_PREFETCHER_H_

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

#include "paging/page_cache.h"
#include "util/status.h"

namespace octoscope::paging {

// The end of one prefetch request (see the header comment for the status codes).
struct PrefetchCompletion {
  PageCache* cache = nullptr;
  uint64_t page = 0;
  Status status;
};

struct PagePrefetcherOptions {
  int io_threads = 2;             // Clamped to [1, 64].
  size_t max_outstanding = 4096;  // Queued + in flight + untaken completions; at least 1.
  // How long one load waits for room in a cache full of pinned pages.
  std::chrono::milliseconds room_timeout{250};
  // How long a page whose read failed is refused (kRecentlyFailed).
  std::chrono::milliseconds failure_hold{10'000};
  // When set, receives every completion on an I/O thread instead of the completion queue.
  std::function<void(const PrefetchCompletion&)> on_complete = nullptr;
};

enum class PrefetchRequestResult {
  kQueued,          // Accepted: one completion will follow (unless cancelled).
  kDuplicate,       // Already queued or in flight: its one completion covers this request too.
  kResident,        // Already in RAM: nothing to do, no completion.
  kQueueFull,       // max_outstanding reached: ask again later.
  kRecentlyFailed,  // Its read failed less than failure_hold ago.
  kShutDown,        // The prefetcher is being destroyed.
};

// Counters since construction; queued and in_flight are current values.
struct PagePrefetcherStats {
  uint64_t queued = 0;      // Requests waiting for an I/O thread, now.
  uint64_t in_flight = 0;   // Loads running, now.
  uint64_t accepted = 0;    // kQueued results.
  uint64_t duplicates = 0;  // kDuplicate results.
  uint64_t resident = 0;    // kResident results.
  uint64_t refused = 0;     // kQueueFull, kRecentlyFailed and kShutDown results.
  uint64_t loaded = 0;      // Completions with status OK.
  uint64_t no_room = 0;     // Completions with kResourceExhausted.
  uint64_t failed = 0;      // Completions with any other error.
  uint64_t cancelled = 0;   // Requests dropped by CancelAll/Detach/shutdown (queued or in flight).
};

class PagePrefetcher {
 public:
  using Options = PagePrefetcherOptions;
  using Stats = PagePrefetcherStats;

  // Starts the I/O threads (std::system_error if they cannot be started).
  explicit PagePrefetcher(PagePrefetcherOptions options = {});
  // Drops queued requests, waits for the loads in flight, joins the threads.
  ~PagePrefetcher();

  PagePrefetcher(const PagePrefetcher&) = delete;
  PagePrefetcher& operator=(const PagePrefetcher&) = delete;

  // Asks for `page` of `cache` to be loaded. Never waits for I/O. REQUIRES: cache != nullptr.
  PrefetchRequestResult Request(PageCache* cache, uint64_t page);

  // Drops the queued requests of `cache` (of all caches) and suppresses the completions of its
  // loads in flight; returns the number of requests dropped or suppressed. Never waits for I/O.
  size_t CancelAll(PageCache* cache);
  size_t CancelAll();

  // CancelAll(cache), then waits until no I/O thread uses `cache`, and forgets it (its remembered
  // failures too). Afterwards `cache` may be destroyed. Not from on_complete.
  void Detach(PageCache* cache);

  // Waits until at least one completion is queued, at most `timeout`; returns whether one is.
  // (With on_complete set nothing is ever queued.)
  bool WaitForCompletion(std::chrono::milliseconds timeout);
  // Takes all queued completions, oldest first.
  std::vector<PrefetchCompletion> TakeCompletions();

  Stats stats() const;

 private:
  struct Key {
    PageCache* cache;
    uint64_t page;
    bool operator==(const Key&) const = default;
  };
  struct KeyHash {
    size_t operator()(const Key& key) const noexcept;
  };
  // A request known to the prefetcher (queued or in flight).
  struct Entry {
    bool in_flight = false;
    uint64_t epoch = 0;  // The cache's epoch when (last) requested; older than current: cancelled.
  };
  // Per cache: its cancellation epoch and how many loads of it are running.
  struct CacheState {
    uint64_t epoch = 0;
    size_t busy = 0;
  };

  void IoLoop() noexcept;
  void ServeOne(std::unique_lock<std::mutex>& lock);
  size_t CancelLocked(PageCache* cache);  // null: all caches.
  bool RecentlyFailedLocked(const Key& key, std::chrono::steady_clock::time_point now);
  void RememberFailureLocked(const Key& key, std::chrono::steady_clock::time_point now);
  size_t OutstandingLocked() const { return queue_.size() + in_flight_ + completions_.size(); }

  const PagePrefetcherOptions options_;

  mutable std::mutex mu_;
  std::condition_variable work_cv_;        // Signalled on new requests and at shutdown.
  std::condition_variable completion_cv_;  // Signalled when a completion is queued.
  std::condition_variable idle_cv_;        // Signalled when a load ends (for Detach).
  // All guarded by mu_. Invariants: every key in queue_ has an entry with !in_flight; entries_ has
  // exactly the queued and in-flight keys; in_flight_ = number of in-flight entries = sum of busy.
  std::deque<Key> queue_;
  std::unordered_map<Key, Entry, KeyHash> entries_;
  std::unordered_map<PageCache*, CacheState> caches_;
  std::unordered_map<Key, std::chrono::steady_clock::time_point, KeyHash> failures_;
  std::vector<PrefetchCompletion> completions_;
  size_t in_flight_ = 0;
  bool stop_ = false;
  Stats stats_;
  std::vector<std::thread> threads_;  // Started last in the constructor.
};

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_PAGING_PAGE_PREFETCHER_H_
