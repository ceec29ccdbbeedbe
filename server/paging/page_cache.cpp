#include "paging/page_cache.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <string>
#include <unordered_set>
#include <utility>

namespace octoscope::paging {
namespace {

using Clock = std::chrono::steady_clock;

constexpr std::chrono::milliseconds kWriterMinBackoff{10};
constexpr std::chrono::milliseconds kWriterMaxBackoff{1000};

// A fraction of `pages`, for the write-behind marks.
uint64_t FractionOf(uint64_t pages, double fraction) {
  return static_cast<uint64_t>(std::floor(static_cast<double>(pages) * fraction));
}

PageCacheOptions Sanitized(PageCacheOptions options) {
  // NaN compares false everywhere: treat it as 0 (write everything behind).
  auto clamp01 = [](double x) { return x > 0 ? std::min(x, 1.0) : 0.0; };
  options.dirty_high_water = clamp01(options.dirty_high_water);
  options.dirty_low_water = std::min(clamp01(options.dirty_low_water), options.dirty_high_water);
  return options;
}

// Runs a store call so that an exception (bad_alloc in a store, a bug) becomes a Status: the cache
// must get to reset its loading/writing flags, or other threads would wait forever.
template <typename Fn>
Status GuardedStoreCall(const char* op, uint64_t page, Fn&& fn) noexcept {
  try {
    return fn();
  } catch (const std::exception& e) {
    return InternalError(std::string("page store ") + op + " of page " + std::to_string(page) +
                         " threw: " + e.what());
  } catch (...) {
    return InternalError(std::string("page store ") + op + " threw");
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// PageHandle

PageHandle::PageHandle(PageHandle&& other) noexcept
    : cache_(std::exchange(other.cache_, nullptr)),
      frame_(std::exchange(other.frame_, nullptr)),
      page_(std::exchange(other.page_, 0)),
      data_(std::exchange(other.data_, nullptr)),
      size_(std::exchange(other.size_, 0)),
      marked_dirty_(std::exchange(other.marked_dirty_, false)) {}

PageHandle& PageHandle::operator=(PageHandle&& other) noexcept {
  if (this != &other) {
    Reset();
    cache_ = std::exchange(other.cache_, nullptr);
    frame_ = std::exchange(other.frame_, nullptr);
    page_ = std::exchange(other.page_, 0);
    data_ = std::exchange(other.data_, nullptr);
    size_ = std::exchange(other.size_, 0);
    marked_dirty_ = std::exchange(other.marked_dirty_, false);
  }
  return *this;
}

PageHandle::~PageHandle() { Reset(); }

void PageHandle::MarkDirty() {
  if (marked_dirty_) return;
  cache_->MarkDirty(static_cast<PageCache::Frame*>(frame_));
  marked_dirty_ = true;
}

void PageHandle::Reset() noexcept {
  if (cache_ == nullptr) return;
  cache_->Unpin(static_cast<PageCache::Frame*>(frame_), marked_dirty_);
  cache_ = nullptr;
  frame_ = nullptr;
  page_ = 0;
  data_ = nullptr;
  size_ = 0;
  marked_dirty_ = false;
}

// ---------------------------------------------------------------------------------------------
// PageCache: construction, budget

PageCache::PageCache(PageStore* store, uint64_t budget_bytes, std::chrono::milliseconds pin_timeout)
    : PageCache(store, budget_bytes, PageCacheOptions{.pin_timeout = pin_timeout}) {}

PageCache::PageCache(PageStore* store, uint64_t budget_bytes, const PageCacheOptions& options)
    : store_(store),
      page_bytes_(store->page_bytes()),
      options_(Sanitized(options)),
      budget_bytes_(budget_bytes),
      capacity_pages_(page_bytes_ == 0 ? 0 : budget_bytes / page_bytes_) {
  if (options_.write_behind) writer_ = std::thread([this] { WriterLoop(); });
}

PageCache::~PageCache() {
  if (writer_.joinable()) {
    {
      std::lock_guard lock(mu_);
      stop_writer_ = true;
    }
    writer_cv_.notify_all();
    writer_.join();
  }
  // Best effort only; callers that care call Flush() themselves and check the result.
  (void)Flush();
}

Status PageCache::SetBudget(uint64_t bytes) {
  std::vector<Buffer> freed;  // Freed after mu_ is released (declared before the lock).
  std::unique_lock lock(mu_);
  budget_bytes_.store(bytes, std::memory_order_relaxed);
  capacity_pages_.store(page_bytes_ == 0 ? 0 : bytes / page_bytes_, std::memory_order_relaxed);
  room_cv_.notify_all();  // Growing makes room; a budget below one page fails waiters at once.
  writer_cv_.notify_all();
  Status first_error;
  std::unordered_set<uint64_t> failed;  // Pages whose write-back failed in this call: skip them.
  while (OverBudgetLocked()) {
    Frame* victim = nullptr;
    for (Frame* f = lru_.head; f != nullptr; f = f->lru.next) {
      if (!f->writing && failed.count(f->page) == 0) {
        victim = f;
        break;
      }
    }
    // The rest is pinned, being written by another thread, or failed: it converges later.
    if (victim == nullptr) break;
    if (!victim->dirty) {
      freed.push_back(EvictLocked(victim));
      continue;
    }
    const uint64_t page = victim->page;
    Status status = WriteBackLocked(victim, lock);
    if (!status.ok()) {
      failed.insert(page);
      if (first_error.ok()) {
        first_error =
            status.WithContext("page cache: writing back page " + std::to_string(page) +
                               " to shrink the budget to " + std::to_string(bytes) + " bytes");
      }
    }
  }
  return first_error;
}

// ---------------------------------------------------------------------------------------------
// PageCache: pinning

Result<PageHandle> PageCache::Pin(uint64_t page) {
  return PinUntil(page, Clock::now() + options_.pin_timeout, nullptr);
}

Status PageCache::Prefetch(uint64_t page, std::chrono::milliseconds room_timeout,
                           bool* read_failed) {
  if (read_failed != nullptr) *read_failed = false;
  const auto timeout =
      std::max(std::chrono::milliseconds{0}, std::min(room_timeout, options_.pin_timeout));
  Result<PageHandle> handle = PinUntil(page, Clock::now() + timeout, read_failed);
  // Dropping the handle unpins the page: it stays resident as the most recently used.
  return handle.ok() ? Status::Ok() : handle.status();
}

Result<PageHandle> PageCache::PinUntil(uint64_t page, Clock::time_point deadline,
                                       bool* read_failed) {
  std::vector<Buffer> freed;  // Evicted above a lowered budget; freed without the lock.
  std::unique_lock lock(mu_);
  // A buffer taken over from an evicted clean page, so a miss at full cache allocates nothing.
  Buffer buffer;
  for (;;) {
    auto it = table_.find(page);
    if (it != table_.end()) {
      Frame* frame = it->second.get();
      if (frame->loading) {
        // Another thread loads this page: wait for it rather than reading it twice.
        state_cv_.wait(lock);
        continue;
      }
      ++stats_.hits;
      return PinFrameLocked(frame);
    }
    const uint64_t capacity = capacity_pages();
    if (capacity == 0) {
      return ResourceExhaustedError("page cache: budget of " + std::to_string(budget_bytes()) +
                                    " bytes cannot hold one page of " +
                                    std::to_string(page_bytes_) + " bytes");
    }
    if (table_.size() < capacity) break;  // A free slot: allocate a fresh buffer.
    Frame* victim = PickVictimLocked();
    if (victim == nullptr) {
      // Everything is pinned (or being written back): sleep until a page is released.
      if (Clock::now() >= deadline) {
        return ResourceExhaustedError(
            "page cache: all " + std::to_string(table_.size()) + " resident pages (budget " +
            std::to_string(budget_bytes()) + " bytes, " + std::to_string(capacity) +
            " pages) stayed pinned as long as this load could wait; cannot load page " +
            std::to_string(page));
      }
      room_cv_.wait_until(lock, deadline);
      continue;
    }
    if (victim->dirty) {
      // Write back, then re-examine everything: the lock was released meanwhile.
      const uint64_t victim_page = victim->page;
      Status status = WriteBackLocked(victim, lock);
      if (!status.ok()) {
        return status.WithContext("page cache: writing back page " + std::to_string(victim_page) +
                                  " to make room for page " + std::to_string(page));
      }
      continue;
    }
    // Clean victim: drop it. Reuse its buffer once there is a free slot (one eviction, unless
    // a lowered budget left the cache above capacity: then keep evicting).
    Buffer evicted = EvictLocked(victim);
    if (table_.size() < capacity) {
      buffer = std::move(evicted);
      break;
    }
    freed.push_back(std::move(evicted));
  }

  // Miss: register a loading frame (it owns the slot from now on), then load without the lock.
  auto owned = std::make_unique<Frame>();
  Frame* frame = owned.get();
  frame->page = page;
  frame->pins = 1;
  table_.emplace(page, std::move(owned));
  ++stats_.misses;
  ++stats_.pinned_pages;
  stats_.peak_resident_bytes = std::max(stats_.peak_resident_bytes, table_.size() * page_bytes_);
  lock.unlock();
  freed.clear();

  // Only this frame's write-back could write `page`, and it has none: so a page at or beyond
  // page_count() is still never-written, i.e. zeros (PageStore contract).
  const bool never_written = page >= store_->page_count();
  bool allocated = false;
  Status status;
  bool failed_read = false;
  if (!buffer) {
    // calloc of fresh memory is free (the kernel hands out zeroed pages); malloc when the read
    // overwrites the buffer anyway.
    buffer.reset(static_cast<std::byte*>(never_written ? std::calloc(1, page_bytes_)
                                                       : std::malloc(page_bytes_)));
    allocated = buffer != nullptr;
    if (!allocated) {
      status = ResourceExhaustedError("page cache: out of memory allocating a page of " +
                                      std::to_string(page_bytes_) + " bytes");
    }
  } else if (never_written) {
    std::memset(buffer.get(), 0, page_bytes_);  // A reused buffer holds the victim's bytes.
  }
  if (buffer && !never_written) {
    status = GuardedStoreCall("read", page, [&] {
      return store_->Read(page, {buffer.get(), page_bytes_});
    });
    failed_read = !status.ok();
  }
  if (read_failed != nullptr) *read_failed = failed_read;
  // A failed load frees its buffer before giving the slot back, so the budget holds.
  if (!status.ok()) buffer.reset();

  lock.lock();
  if (allocated) ++stats_.buffer_allocations;
  if (!status.ok()) {
    if (failed_read) ++stats_.failed_reads;
    table_.erase(page);
    --stats_.pinned_pages;
    state_cv_.notify_all();  // Waiters for this page retry the load themselves.
    room_cv_.notify_all();   // The slot is free again.
    return status;
  }
  frame->buffer = std::move(buffer);
  frame->loading = false;
  if (never_written) {
    ++stats_.zero_pages;
  } else {
    stats_.bytes_read += page_bytes_;
  }
  state_cv_.notify_all();
  return PageHandle(this, frame, page, frame->buffer.get(), page_bytes_);
}

std::optional<PageHandle> PageCache::TryPin(uint64_t page) {
  std::lock_guard lock(mu_);
  auto it = table_.find(page);
  if (it == table_.end() || it->second->loading) return std::nullopt;
  ++stats_.hits;
  return PinFrameLocked(it->second.get());
}

bool PageCache::IsResident(uint64_t page) const {
  std::lock_guard lock(mu_);
  auto it = table_.find(page);
  return it != table_.end() && !it->second->loading;
}

PageHandle PageCache::PinFrameLocked(Frame* frame) {
  if (frame->pins++ == 0) {
    LruRemoveLocked(frame);
    ++stats_.pinned_pages;
  }
  return PageHandle(this, frame, frame->page, frame->buffer.get(), page_bytes_);
}

void PageCache::Unpin(Frame* frame, bool marked_dirty) noexcept {
  Buffer dropped;  // Freed after the lock is released (declared before it).
  std::lock_guard lock(mu_);
  if (marked_dirty) {
    --frame->writers;
    state_cv_.notify_all();  // Flush may be waiting for this writer.
  }
  if (--frame->pins != 0) return;
  --stats_.pinned_pages;
  if (OverBudgetLocked() && !frame->dirty && !frame->writing) {
    dropped = EvictLocked(frame);  // Above a lowered budget a clean page goes at once (no I/O).
  } else {
    LruPushMruLocked(frame);
    if (frame->dirty && options_.write_behind) writer_cv_.notify_one();
  }
  room_cv_.notify_all();
}

void PageCache::MarkDirty(Frame* frame) {
  std::unique_lock lock(mu_);
  // The in-flight write reads the buffer: modifications must wait until it is done.
  state_cv_.wait(lock, [frame] { return !frame->writing; });
  ++frame->writers;
  SetDirtyLocked(frame, true);
}

// ---------------------------------------------------------------------------------------------
// PageCache: write-back

Status PageCache::Flush() {
  std::vector<Buffer> freed;  // Declared before the lock: freed after it is released.
  const auto deadline = Clock::now() + options_.pin_timeout;
  std::unique_lock lock(mu_);
  std::vector<uint64_t> pages;
  for (const auto& [page, frame] : table_) {
    if (frame->dirty) pages.push_back(page);
  }
  // Ascending page order: sequential I/O for file stores.
  std::sort(pages.begin(), pages.end());
  Status first_error;
  for (uint64_t page : pages) {
    for (;;) {
      auto it = table_.find(page);
      // Gone or clean: someone else (an evictor, write-behind) wrote it back meanwhile.
      if (it == table_.end() || !it->second->dirty) break;
      Frame* frame = it->second.get();
      if (frame->writers > 0 || frame->writing) {
        // A holder may be modifying it, or another write is in flight: wait for either to end.
        if (Clock::now() >= deadline) {
          if (first_error.ok()) {
            first_error = ResourceExhaustedError("page cache flush: page " + std::to_string(page) +
                                                 " stayed marked dirty by a live handle for " +
                                                 std::to_string(options_.pin_timeout.count()) +
                                                 " ms; not written");
          }
          break;
        }
        state_cv_.wait_until(lock, deadline);
        continue;
      }
      Status status = WriteBackLocked(frame, lock);
      if (!status.ok() && first_error.ok()) {
        first_error = status.WithContext("page cache flush");
      }
      break;
    }
  }
  TrimToBudgetLocked(freed);
  // A background write failure is reported once, here.
  Status background = std::exchange(write_behind_error_, Status::Ok());
  lock.unlock();
  // Sync even after a failed write: the pages that did reach the store become durable.
  Status sync = store_->Sync();
  if (!first_error.ok()) return first_error;
  if (!background.ok()) return background;
  return sync.ok() ? sync : sync.WithContext("page cache flush");
}

Status PageCache::WriteBackLocked(Frame* frame, std::unique_lock<std::mutex>& lock) {
  // `writing` keeps the frame and its buffer alive and unmodified while mu_ is released: no
  // evictor picks it, Flush waits for it, and MarkDirty() blocks until it is cleared.
  frame->writing = true;
  const uint64_t page = frame->page;
  const std::span<const std::byte> data(frame->buffer.get(), page_bytes_);
  lock.unlock();
  Status status = GuardedStoreCall("write", page, [&] { return store_->Write(page, data); });
  lock.lock();
  frame->writing = false;
  if (status.ok()) {
    // No MarkDirty could happen during the write, so the store now equals the RAM copy.
    SetDirtyLocked(frame, false);
    ++stats_.writebacks;
    stats_.bytes_written += page_bytes_;
  } else {
    // Keep the page dirty and resident: the RAM copy is the only good one.
    ++stats_.failed_writes;
    // The writer skipped this page while it was being written: it is a candidate again.
    if (options_.write_behind) writer_cv_.notify_one();
  }
  state_cv_.notify_all();
  room_cv_.notify_all();
  return status;
}

PageCache::Frame* PageCache::PickVictimLocked() const {
  for (Frame* frame = lru_.head; frame != nullptr; frame = frame->lru.next) {
    if (!frame->writing) return frame;
  }
  return nullptr;
}

PageCache::Buffer PageCache::EvictLocked(Frame* frame) {
  LruRemoveLocked(frame);
  Buffer buffer = std::move(frame->buffer);
  table_.erase(frame->page);  // Destroys the frame.
  ++stats_.evictions;
  room_cv_.notify_all();
  return buffer;
}

void PageCache::TrimToBudgetLocked(std::vector<Buffer>& freed) {
  Frame* frame = lru_.head;
  while (frame != nullptr && OverBudgetLocked()) {
    Frame* next = frame->lru.next;
    if (!frame->dirty && !frame->writing) freed.push_back(EvictLocked(frame));
    frame = next;
  }
}

// ---------------------------------------------------------------------------------------------
// PageCache: write-behind

bool PageCache::WriteBehindWantedLocked() {
  const uint64_t capacity = capacity_pages();
  if (stats_.dirty_pages > FractionOf(capacity, options_.dirty_high_water)) {
    writer_active_ = true;
  } else if (stats_.dirty_pages <= FractionOf(capacity, options_.dirty_low_water)) {
    writer_active_ = false;
  }
  // Above a lowered budget, dirty unpinned pages are written so that they can be dropped.
  return writer_active_ || OverBudgetLocked();
}

void PageCache::WriterLoop() noexcept {
  std::unique_lock lock(mu_);
  std::chrono::milliseconds backoff{0};
  while (!stop_writer_) {
    try {
      // The oldest unpinned dirty page without a write in flight.
      Frame* frame = nullptr;
      if (WriteBehindWantedLocked()) {
        for (Frame* f = dirty_lru_.head; f != nullptr; f = f->dirty_lru.next) {
          if (!f->writing) {
            frame = f;
            break;
          }
        }
      }
      if (frame == nullptr) {
        writer_cv_.wait(lock);
        continue;
      }
      const uint64_t page = frame->page;
      Status status = WriteBackLocked(frame, lock);
      if (status.ok()) {
        ++stats_.write_behind_writes;
        backoff = std::chrono::milliseconds{0};
        if (OverBudgetLocked()) {
          std::vector<Buffer> freed;
          TrimToBudgetLocked(freed);
          lock.unlock();
          freed.clear();
          lock.lock();
        }
        continue;
      }
      if (write_behind_error_.ok()) {
        write_behind_error_ =
            status.WithContext("page cache write-behind of page " + std::to_string(page));
      }
      // Let the other dirty pages go first, and do not spin on a failing store.
      if (frame->dirty_lru.linked) {
        ListRemove(dirty_lru_, &Frame::dirty_lru, frame);
        ListPushBack(dirty_lru_, &Frame::dirty_lru, frame);
      }
      backoff = std::clamp(backoff * 2, kWriterMinBackoff, kWriterMaxBackoff);
      writer_cv_.wait_for(lock, backoff, [this] { return stop_writer_; });
    } catch (...) {
      // Only a std::string allocation can throw here; give up this round and retry later.
      if (!lock.owns_lock()) lock.lock();
      writer_cv_.wait_for(lock, kWriterMaxBackoff, [this] { return stop_writer_; });
    }
  }
}

// ---------------------------------------------------------------------------------------------
// PageCache: bookkeeping

PageCacheStats PageCache::stats() const {
  std::lock_guard lock(mu_);
  Stats stats = stats_;
  stats.resident_bytes = table_.size() * page_bytes_;
  stats.budget_bytes = budget_bytes();
  return stats;
}

void PageCache::ListPushBack(FrameList& list, Link Frame::*link, Frame* frame) {
  Link& l = frame->*link;
  l.prev = list.tail;
  l.next = nullptr;
  if (list.tail != nullptr)
    (list.tail->*link).next = frame;
  else
    list.head = frame;
  list.tail = frame;
  l.linked = true;
}

void PageCache::ListRemove(FrameList& list, Link Frame::*link, Frame* frame) {
  Link& l = frame->*link;
  if (!l.linked) return;
  if (l.prev != nullptr)
    (l.prev->*link).next = l.next;
  else
    list.head = l.next;
  if (l.next != nullptr)
    (l.next->*link).prev = l.prev;
  else
    list.tail = l.prev;
  l = Link{};
}

void PageCache::LruPushMruLocked(Frame* frame) {
  ListPushBack(lru_, &Frame::lru, frame);
  if (frame->dirty) ListPushBack(dirty_lru_, &Frame::dirty_lru, frame);
}

void PageCache::LruRemoveLocked(Frame* frame) {
  ListRemove(lru_, &Frame::lru, frame);
  ListRemove(dirty_lru_, &Frame::dirty_lru, frame);
}

void PageCache::SetDirtyLocked(Frame* frame, bool dirty) {
  if (frame->dirty == dirty) return;
  frame->dirty = dirty;
  if (dirty) {
    ++stats_.dirty_pages;
    // Only pinned frames become dirty (MarkDirty); they join dirty_lru_ when unpinned.
  } else {
    --stats_.dirty_pages;
    ListRemove(dirty_lru_, &Frame::dirty_lru, frame);
  }
}

}  // namespace octoscope::paging
