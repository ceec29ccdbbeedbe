// PageCache: the RAM side of the out-of-core design. Keeps a working set of a PageStore's pages in
// memory under a HARD byte budget that can be changed at run time, hands them out through pin
// handles, evicts the least recently used unpinned page when it needs room, writes pages back
// only when they are dirty, and (optionally) writes dirty pages back in the background.
//
// Budget: every page buffer the cache owns (loading, resident, or being written back) counts
// against the budget, and a buffer is reserved BEFORE it is allocated. A page is admitted (its
// load starts) only while resident_pages < capacity_pages = budget_bytes / page_bytes, so
//     resident_bytes <= budget_bytes
// at every instant, except after SetBudget() LOWERED the budget: then pages that cannot be dropped
// at once (pinned, dirty with a failed write-back, being written) stay, and
//     resident_bytes <= max(budget_bytes, resident_bytes when the budget was lowered),
// resident_bytes never grows while it is above the budget, and it drops to the budget as those
// pages are unpinned (clean ones are dropped by their Unpin) and written back (by write-behind,
// the next Pin that needs room, Flush or SetBudget). stats().peak_resident_bytes is at most the
// largest budget ever set. Pinned pages are never evicted; when every resident page is pinned,
// Pin() of a missing page waits (sleeps on a condition variable, like the paper's construction
// threads) until some page is unpinned or the budget grows. The wait is bounded by pin_timeout
// (default 60 s): then Pin returns kResourceExhausted instead of deadlocking silently (e.g. when
// the budget holds fewer pages than the threads pin at once). While the budget is smaller than one
// page every Pin of a missing page fails at once with kResourceExhausted.
//
// I/O: reads (misses) and write-backs run WITHOUT the cache-wide lock, so hits on other pages, and
// other misses, proceed meanwhile; no page buffer is allocated or freed under the lock. Concurrent
// Pins of the same missing page load it once: the later callers wait for that load (and count as
// hits). A page that fails to load is not cached (each waiter then tries the load itself and
// reports its own error). A page at or beyond store->page_count() was never written: it is not
// read at all but zero-filled exactly once (a fresh buffer comes zeroed from the allocator, a
// reused one is cleared). A load at full cache reuses the evicted page's buffer (no allocation).
//
// Write-back: only dirty pages are written (on eviction, by write-behind, and in Flush); clean
// pages are dropped. A failed write-back never loses data: the page stays resident and dirty (and
// stays the next eviction candidate, so the write is retried by the next Pin that needs room), and
// the error is returned from that Pin()/Flush()/SetBudget(). A store that may tear a page on a
// failed write is fine: the cache keeps the whole page and rewrites all of it.
//
// Write-behind (PageCacheOptions::write_behind): one background thread, owned by the cache and
// joined by its destructor, writes dirty UNPINNED pages back, least recently used first, whenever
// more than dirty_high_water * capacity_pages pages are dirty, until at most dirty_low_water *
// capacity_pages are, leaving them resident and clean; it also writes (and then drops) dirty
// unpinned pages while the cache is above a lowered budget. So eviction rarely waits for a write,
// writes overlap computation, and a final Flush() has little left to do. It follows the dirty
// protocol below. A failed background write keeps the page dirty (moved behind the other dirty
// pages; the writer backs off, 10 ms doubling up to 1 s, while writes keep failing), and the first
// such error since the last Flush is returned by the next Flush() — even when the page was written
// successfully later, so the caller learns that the store failed; a second Flush then returns OK
// if everything got written. No exception leaves the thread.
//
// Dirty protocol: call MarkDirty() on a handle BEFORE modifying its data (once is enough). While a
// page is being written back, MarkDirty() waits for that one write to finish (the write reads the
// buffer; the modifications must not race with it). Pages pinned only for reading may be written
// back concurrently with their readers.
//
// LRU: a page becomes most-recently-used when its last pin is released; victims are taken from the
// least-recently-used end (skipping pages whose write-back is in flight).
//
// Thread safety: all member functions are thread-safe. TryPin, IsResident, stats, budget_bytes and
// capacity_pages never wait for I/O (they take the cache lock briefly, or none). A PageHandle may
// be moved between threads but one handle must not be used by two threads at once; the bytes of a
// page may be read by all holders at once but modified by one holder at a time (coordinating
// writers of one page, e.g. by striped locks, is the caller's job). All handles must be released
// before the cache is destroyed; the store must outlive the cache, and while the cache exists it
// must be the only writer of the store (it relies on page_count() to skip never-written pages).
#ifndef OCTOSCOPE_PAGING_PAGE_CACHE_H_
#define OCTOSCOPE_PAGING_PAGE_CACHE_H_

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <thread>
#include <unordered_map>
#include <vector>

#include "paging/page_store.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::paging {

class PageCache;

inline constexpr std::chrono::milliseconds kDefaultPinTimeout{60'000};

// Construction options of a PageCache.
struct PageCacheOptions {
  // How long Pin waits for room in a cache full of pinned pages (and Flush for a page's writers).
  std::chrono::milliseconds pin_timeout = kDefaultPinTimeout;
  // Start the background writer (see the header comment).
  bool write_behind = false;
  // Write-behind starts when more than dirty_high_water * capacity_pages pages are dirty and stops
  // at dirty_low_water * capacity_pages. Fractions of the CURRENT budget, clamped to [0, 1];
  // a low water above the high water is lowered to it.
  double dirty_high_water = 0.5;
  double dirty_low_water = 0.25;
};

// Counters since construction. resident_bytes, budget_bytes, pinned_pages and dirty_pages are
// current values; the rest only grow.
struct PageCacheStats {
  uint64_t budget_bytes = 0;         // The budget now (SetBudget).
  uint64_t resident_bytes = 0;       // Page buffers held now (loading + resident + writing back).
  uint64_t peak_resident_bytes = 0;  // Maximum of resident_bytes ever; <= largest budget set.
  uint64_t hits = 0;                 // Pins / successful TryPins served without starting a load.
  uint64_t misses = 0;               // Loads started by Pin or Prefetch (successful or not).
  uint64_t evictions = 0;            // Pages dropped from RAM (always clean then).
  uint64_t writebacks = 0;           // Successful page writes to the store (all causes).
  uint64_t write_behind_writes = 0;  // Those of them done by the background writer.
  uint64_t bytes_read = 0;           // Bytes successfully read from the store.
  uint64_t bytes_written = 0;        // Bytes successfully written to the store.
  uint64_t zero_pages = 0;           // Loads of never-written pages: zero-filled, not read.
  uint64_t buffer_allocations = 0;   // Page buffers allocated (a load at full cache reuses one).
  uint64_t failed_reads = 0;         // Store reads that returned an error.
  uint64_t failed_writes = 0;        // Store writes that returned an error (all causes).
  uint64_t pinned_pages = 0;         // Pages with at least one live handle, now.
  uint64_t dirty_pages = 0;          // Resident pages not yet written back, now.
};

// A pin on one resident page: while it lives, the page stays in RAM at the same address.
// Move-only; the destructor (or Reset) unpins and never throws. A default-constructed or
// moved-from handle is empty (valid() == false).
class PageHandle {
 public:
  PageHandle() = default;
  PageHandle(PageHandle&& other) noexcept;
  PageHandle& operator=(PageHandle&& other) noexcept;
  PageHandle(const PageHandle&) = delete;
  PageHandle& operator=(const PageHandle&) = delete;
  ~PageHandle();

  bool valid() const { return cache_ != nullptr; }

  // The page's bytes (exactly page_bytes). REQUIRES: valid(). Modify only after MarkDirty().
  std::span<std::byte> data() { return {data_, size_}; }
  std::span<const std::byte> data() const { return {data_, size_}; }

  // Declares that this holder modifies the page, so it is written back before it is dropped.
  // Call BEFORE the first modification; later calls on the same handle are free. May wait for an
  // in-flight write-back of this page (one page write) to finish. REQUIRES: valid().
  void MarkDirty();

  // The page index. REQUIRES: valid().
  uint64_t page() const { return page_; }

  // Unpins now (the handle becomes empty). No-op on an empty handle. Never does I/O: a clean page
  // above a lowered budget is dropped here, a dirty one is left to the writers.
  void Reset() noexcept;

 private:
  friend class PageCache;
  PageHandle(PageCache* cache, void* frame, uint64_t page, std::byte* data, size_t size)
      : cache_(cache), frame_(frame), page_(page), data_(data), size_(size) {}

  PageCache* cache_ = nullptr;
  void* frame_ = nullptr;  // A PageCache::Frame; stable while pinned.
  uint64_t page_ = 0;
  std::byte* data_ = nullptr;
  size_t size_ = 0;
  bool marked_dirty_ = false;  // MarkDirty() already registered this handle as a writer.
};

class PageCache {
 public:
  using Stats = PageCacheStats;
  using Options = PageCacheOptions;
  static constexpr std::chrono::milliseconds kDefaultPinTimeout = paging::kDefaultPinTimeout;

  // `store` must outlive the cache. The budget holds floor(budget_bytes / page_bytes) pages.
  // `pin_timeout` bounds how long Pin waits for a pinned-full cache (see the header comment).
  PageCache(PageStore* store, uint64_t budget_bytes,
            std::chrono::milliseconds pin_timeout = kDefaultPinTimeout);
  // As above with all options; starts the write-behind thread when options.write_behind
  // (std::system_error if the thread cannot be started).
  PageCache(PageStore* store, uint64_t budget_bytes, const PageCacheOptions& options);
  // Stops and joins the write-behind thread, then makes a best-effort write-back of dirty pages
  // (errors are lost: call Flush() first and check it). REQUIRES: no live handles.
  ~PageCache();

  PageCache(const PageCache&) = delete;
  PageCache& operator=(const PageCache&) = delete;

  // Pins `page`, loading it from the store on a miss (evicting, and if needed writing back, the
  // least recently used unpinned page first). Blocks while the cache is full of pinned pages, at
  // most pin_timeout (then kResourceExhausted). Errors: the store's read error (nothing is cached),
  // a write-back error of the eviction victim (the victim stays dirty and resident), or
  // kResourceExhausted (budget smaller than a page, timeout, out of memory).
  Result<PageHandle> Pin(uint64_t page);

  // Pins `page` only if it is resident and loaded. Never does I/O, never waits for a load or for
  // room (it takes the cache lock briefly). For render threads: nullopt means "not in RAM now".
  std::optional<PageHandle> TryPin(uint64_t page);

  // Whether `page` is resident and loaded now (a hint: it may be evicted right after). Takes the
  // cache lock briefly; unlike TryPin it neither pins nor counts nor touches the LRU order.
  bool IsResident(uint64_t page) const;

  // For prefetchers (PagePrefetcher): makes `page` resident like Pin, then leaves it unpinned and
  // most recently used (it may be evicted at any later time). Waits for room at most
  // min(room_timeout, pin_timeout). Returns OK when the page was resident on return, or Pin's
  // errors. `read_failed` (optional) is set to whether the error is the store's read of `page`
  // itself (and not, e.g., no room or a victim's failed write-back).
  Status Prefetch(uint64_t page, std::chrono::milliseconds room_timeout,
                  bool* read_failed = nullptr);

  // Writes every page that is dirty when Flush is called, then Sync()s the store. A dirty page that
  // a live handle has marked dirty is waited for until that handle is released (bounded by
  // pin_timeout, then kResourceExhausted for that page) — so a thread must not call Flush while it
  // holds a handle it marked dirty. Pages that fail to write stay dirty; Flush continues with the
  // others and returns the first error, else the first write-behind error since the last Flush
  // (see the header comment). Pages dirtied after the call began may or may not be written.
  // Clean unpinned pages above a lowered budget are dropped.
  Status Flush();

  // Changes the budget to `bytes` (capacity floor(bytes / page_bytes) pages) at once: Pins
  // waiting for room re-check it (growing wakes them). Shrinking then evicts unpinned pages, least
  // recently used first, writing dirty ones back on the calling thread, until resident_bytes <=
  // bytes; pinned pages, pages being written by others, and pages whose write-back fails stay
  // (see "Budget" in the header comment for how the cache converges). Never waits for a pin.
  // Returns the first write-back error (the page stays resident and dirty), else OK — also when
  // pinned pages keep resident_bytes above the new budget for now.
  Status SetBudget(uint64_t bytes);

  Stats stats() const;

  uint64_t page_bytes() const { return page_bytes_; }
  // The current budget and the pages it holds (budget_bytes / page_bytes). Lock-free reads of
  // values that SetBudget may change at any time.
  uint64_t budget_bytes() const { return budget_bytes_.load(std::memory_order_relaxed); }
  uint64_t capacity_pages() const { return capacity_pages_.load(std::memory_order_relaxed); }
  PageStore* store() const { return store_; }

 private:
  friend class PageHandle;

  struct FreeDeleter {
    void operator()(std::byte* p) const noexcept { std::free(p); }
  };
  // malloc/calloc'ed, so a never-written page can come zeroed from the allocator (fresh memory).
  using Buffer = std::unique_ptr<std::byte[], FreeDeleter>;

  struct Frame;
  // A frame's membership in one intrusive list.
  struct Link {
    Frame* prev = nullptr;  // Towards the head (older).
    Frame* next = nullptr;
    bool linked = false;
  };
  // An intrusive doubly linked list of frames through one Link member; head = oldest.
  struct FrameList {
    Frame* head = nullptr;
    Frame* tail = nullptr;
  };
  // One page known to the cache. Frames live in table_; a frame with pins > 0 or writing == true
  // is never erased, so handles and in-flight write-backs may keep raw pointers to it.
  // State (all fields guarded by mu_):
  //   loading (buffer == null, pins >= 1: the loader's pin) --read ok--> ready (buffer set)
  //   loading --read failed--> erased.
  //   A ready frame may be `writing` (its write-back is in flight with mu_ released).
  struct Frame {
    uint64_t page = 0;
    bool loading = true;
    bool dirty = false;    // RAM copy newer than the store's.
    bool writing = false;  // A write-back of `buffer` is in flight.
    uint32_t pins = 0;     // Live handles (+ the loader while loading).
    uint32_t writers = 0;  // Live handles that called MarkDirty; > 0 implies dirty.
    Buffer buffer;         // page_bytes_; stable while pinned or writing.
    Link lru;              // In lru_ iff ready and pins == 0.
    Link dirty_lru;        // In dirty_lru_ iff in lru_ and dirty.
  };

  static void ListPushBack(FrameList& list, Link Frame::*link, Frame* frame);
  static void ListRemove(FrameList& list, Link Frame::*link, Frame* frame);

  Result<PageHandle> PinUntil(uint64_t page, std::chrono::steady_clock::time_point deadline,
                              bool* read_failed);
  void Unpin(Frame* frame, bool marked_dirty) noexcept;
  void MarkDirty(Frame* frame);
  // Writes `frame` back with mu_ released. REQUIRES: lock holds mu_; frame ready, dirty, not
  // writing, writers == 0. On return (lock held again) the frame still exists.
  Status WriteBackLocked(Frame* frame, std::unique_lock<std::mutex>& lock);
  // The least recently used unpinned frame without a write-back in flight, or null.
  Frame* PickVictimLocked() const;
  // Removes an unpinned, clean, not-writing frame from the cache; returns its buffer (for reuse,
  // or to be freed by the caller after releasing mu_).
  Buffer EvictLocked(Frame* frame);
  // Evicts clean unpinned frames (LRU first) while above the budget; buffers go to `freed`.
  void TrimToBudgetLocked(std::vector<Buffer>& freed);
  PageHandle PinFrameLocked(Frame* frame);
  // Appends to / removes from lru_, keeping dirty_lru_ = the dirty frames of lru_.
  void LruPushMruLocked(Frame* frame);
  void LruRemoveLocked(Frame* frame);
  void SetDirtyLocked(Frame* frame, bool dirty);
  bool OverBudgetLocked() const { return table_.size() > capacity_pages(); }
  // Updates the write-behind hysteresis; true when the writer should write a page now.
  bool WriteBehindWantedLocked();
  void WriterLoop() noexcept;

  PageStore* const store_;
  const uint64_t page_bytes_;
  const Options options_;

  mutable std::mutex mu_;
  // Signalled when a load or a write-back finishes, or a writer handle is released.
  std::condition_variable state_cv_;
  // Signalled when a page becomes evictable, a buffer slot is freed, or the budget changes.
  std::condition_variable room_cv_;
  // Signalled when the write-behind thread may have work (or must stop).
  std::condition_variable writer_cv_;
  // Written only under mu_ (SetBudget), readable without it. capacity = budget / page_bytes_.
  std::atomic<uint64_t> budget_bytes_;
  std::atomic<uint64_t> capacity_pages_;
  // Guarded by mu_. Every frame owns one budget slot (its buffer, allocated or about to be), so
  // resident_bytes = table_.size() * page_bytes_; a frame is added only while table_.size() <
  // capacity_pages_ (see "Budget" in the header comment).
  std::unordered_map<uint64_t, std::unique_ptr<Frame>> table_;
  // Intrusive LRU list (guarded by mu_) of exactly the ready frames with pins == 0.
  FrameList lru_;
  // Intrusive list (guarded by mu_) of exactly the LRU frames that are dirty, in LRU order except
  // for frames whose background write failed (moved to the tail). Write-behind takes its head.
  FrameList dirty_lru_;
  Stats stats_;  // Guarded by mu_; resident_bytes and budget_bytes are derived in stats().
  // Write-behind state, guarded by mu_.
  bool writer_active_ = false;  // Hysteresis: between the high and the low water mark.
  bool stop_writer_ = false;
  Status write_behind_error_;  // First failed background write since the last Flush.
  std::thread writer_;         // Started last in the constructor, joined first in the destructor.
};

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_PAGING_PAGE_CACHE_H_
