// PageCache: the RAM side of the out-of-core design. Keeps a working set of a PageStore's pages in
// memory under a HARD byte budget, hands them out through pin handles, evicts the least recently
// used unpinned page when it needs room, and writes pages back only when they are dirty.
//
// Budget: every page buffer the cache owns (loading, resident, or being written back) counts
// against the budget, and a buffer is reserved BEFORE it is allocated, so at every instant
//     resident_bytes = resident pages * page_bytes <= budget_bytes
// and stats().peak_resident_bytes <= budget_bytes. Pinned pages are never evicted; when every
// resident page is pinned, Pin() of a missing page waits (sleeps on a condition variable, like the
// paper's construction threads) until some page is unpinned. The wait is bounded by pin_timeout
// (default 60 s): then Pin returns kResourceExhausted instead of deadlocking silently (e.g. when
// the budget holds fewer pages than the threads pin at once). A budget smaller than one page makes
// every Pin of a missing page fail at once with kResourceExhausted.
//
// I/O: reads (misses) and write-backs run WITHOUT the cache-wide lock, so hits on other pages, and
// other misses, proceed meanwhile. Concurrent Pins of the same missing page load it once: the
// later callers wait for that load (and count as hits). A page that fails to load is not cached
// (each waiter then tries the load itself and reports its own error).
//
// Write-back: only dirty pages are written (on eviction and in Flush); clean pages are dropped.
// A failed write-back never loses data: the page stays resident and dirty (and stays the next
// eviction candidate, so the write is retried by the next Pin that needs room), and the error is
// returned from that Pin()/Flush(). A store that may tear a page on a failed write is fine: the
// cache keeps the whole page and rewrites all of it.
//
// Dirty protocol: call MarkDirty() on a handle BEFORE modifying its data (once is enough). While a
// page is being written back, MarkDirty() waits for that one write to finish (the write reads the
// buffer; the modifications must not race with it). Pages pinned only for reading may be written
// back concurrently with their readers.
//
// LRU: a page becomes most-recently-used when its last pin is released; victims are taken from the
// least-recently-used end (skipping pages whose write-back is in flight).
//
// Thread safety: all member functions are thread-safe. A PageHandle may be moved between threads
// but one handle must not be used by two threads at once; the bytes of a page may be read by all
// holders at once but modified by one holder at a time (coordinating writers of one page, e.g. by
// striped locks, is the caller's job). All handles must be released before the cache is
// destroyed; the store must outlive the cache.
#ifndef OCTOSCOPE_PAGING_PAGE_CACHE_H_
#define OCTOSCOPE_PAGING_PAGE_CACHE_H_

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <unordered_map>

#include "paging/page_store.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::paging {

class PageCache;

// Counters since construction. resident_bytes is the current value; the rest only grow.
struct PageCacheStats {
  uint64_t resident_bytes = 0;       // Page buffers held now (loading + resident + writing back).
  uint64_t peak_resident_bytes = 0;  // Maximum of resident_bytes ever; <= budget_bytes.
  uint64_t hits = 0;                 // Pins / successful TryPins served without starting a load.
  uint64_t misses = 0;               // Loads started by Pin (successful or not).
  uint64_t evictions = 0;            // Pages dropped from RAM to make room (always clean then).
  uint64_t writebacks = 0;           // Successful page writes to the store (eviction or Flush).
  uint64_t bytes_read = 0;           // Bytes successfully read from the store.
  uint64_t bytes_written = 0;        // Bytes successfully written to the store.
  uint64_t failed_reads = 0;         // Store reads that returned an error.
  uint64_t failed_writes = 0;        // Store writes that returned an error.
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

  // Unpins now (the handle becomes empty). No-op on an empty handle.
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
  static constexpr std::chrono::milliseconds kDefaultPinTimeout{60'000};

  // `store` must outlive the cache. The budget holds floor(budget_bytes / page_bytes) pages.
  // `pin_timeout` bounds how long Pin waits for a pinned-full cache (see the header comment).
  PageCache(PageStore* store, uint64_t budget_bytes,
            std::chrono::milliseconds pin_timeout = kDefaultPinTimeout);
  // Makes a best-effort write-back of dirty pages (errors are lost: call Flush() first and check
  // it). REQUIRES: no live handles.
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

  // Writes every page that is dirty when Flush is called, then Sync()s the store. A dirty page that
  // a live handle has marked dirty is waited for until that handle is released (bounded by
  // pin_timeout, then kResourceExhausted for that page) — so a thread must not call Flush while it
  // holds a handle it marked dirty. Pages that fail to write stay dirty; Flush continues with the
  // others and returns the first error. Pages dirtied after the call began may or may not be
  // written.
  Status Flush();

  Stats stats() const;

  uint64_t page_bytes() const { return page_bytes_; }
  uint64_t budget_bytes() const { return budget_bytes_; }
  // Pages the budget holds: budget_bytes / page_bytes.
  uint64_t capacity_pages() const { return capacity_pages_; }
  PageStore* store() const { return store_; }

 private:
  friend class PageHandle;

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
    bool in_lru = false;
    uint32_t pins = 0;                    // Live handles (+ the loader while loading).
    uint32_t writers = 0;                 // Live handles that called MarkDirty; > 0 implies dirty.
    std::unique_ptr<std::byte[]> buffer;  // page_bytes_; stable while pinned or writing.
    Frame* lru_prev = nullptr;            // Towards the least recently used end.
    Frame* lru_next = nullptr;
  };

  void Unpin(Frame* frame, bool marked_dirty) noexcept;
  void MarkDirty(Frame* frame);
  // Writes `frame` back with mu_ released. REQUIRES: lock holds mu_; frame ready, dirty, not
  // writing, writers == 0.
  Status WriteBackLocked(Frame* frame, std::unique_lock<std::mutex>& lock);
  // The least recently used unpinned frame without a write-back in flight, or null.
  Frame* PickVictimLocked() const;
  PageHandle PinFrameLocked(Frame* frame);
  void LruPushMruLocked(Frame* frame);
  void LruRemoveLocked(Frame* frame);
  void SetDirtyLocked(Frame* frame, bool dirty);

  PageStore* const store_;
  const uint64_t page_bytes_;
  const uint64_t budget_bytes_;
  const uint64_t capacity_pages_;
  const std::chrono::milliseconds pin_timeout_;

  mutable std::mutex mu_;
  // Signalled when a load or a write-back finishes, or a writer handle is released.
  std::condition_variable state_cv_;
  // Signalled when a page becomes evictable or a buffer slot is freed.
  std::condition_variable room_cv_;
  // Guarded by mu_. Invariant: every frame owns one budget slot (its buffer, allocated or about
  // to be), so table_.size() <= capacity_pages_ and resident_bytes = table_.size() * page_bytes_.
  std::unordered_map<uint64_t, std::unique_ptr<Frame>> table_;
  // Intrusive LRU list (guarded by mu_) of exactly the ready frames with pins == 0; head = least
  // recently used.
  Frame* lru_head_ = nullptr;
  Frame* lru_tail_ = nullptr;
  Stats stats_;  // Guarded by mu_; resident_bytes is derived in stats().
};

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_PAGING_PAGE_CACHE_H_
