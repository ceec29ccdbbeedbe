#include "paging/page_cache.h"

#include <algorithm>
#include <new>
#include <string>
#include <utility>
#include <vector>

namespace octoscope::paging {

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
// PageCache

PageCache::PageCache(PageStore* store, uint64_t budget_bytes, std::chrono::milliseconds pin_timeout)
    : store_(store),
      page_bytes_(store->page_bytes()),
      budget_bytes_(budget_bytes),
      capacity_pages_(page_bytes_ == 0 ? 0 : budget_bytes / page_bytes_),
      pin_timeout_(pin_timeout) {}

PageCache::~PageCache() {
  // Best effort only; callers that care call Flush() themselves and check the result.
  (void)Flush();
}

Result<PageHandle> PageCache::Pin(uint64_t page) {
  if (capacity_pages_ == 0) {
    return ResourceExhaustedError("page cache: budget of " + std::to_string(budget_bytes_) +
                                  " bytes cannot hold one page of " + std::to_string(page_bytes_) +
                                  " bytes");
  }
  const auto deadline = std::chrono::steady_clock::now() + pin_timeout_;
  std::unique_lock lock(mu_);
  // A buffer taken over from an evicted clean page, so a miss at full cache allocates nothing.
  std::unique_ptr<std::byte[]> buffer;
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
    if (table_.size() < capacity_pages_) break;  // A free slot: allocate a fresh buffer.
    Frame* victim = PickVictimLocked();
    if (victim == nullptr) {
      // Everything is pinned (or being written back): sleep until a page is released.
      if (std::chrono::steady_clock::now() >= deadline) {
        return ResourceExhaustedError(
            "page cache: all " + std::to_string(capacity_pages_) + " pages of the " +
            std::to_string(budget_bytes_) + "-byte budget stayed pinned for " +
            std::to_string(pin_timeout_.count()) + " ms; cannot load page " + std::to_string(page));
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
    // Clean victim: drop it and reuse its buffer.
    LruRemoveLocked(victim);
    buffer = std::move(victim->buffer);
    table_.erase(victim->page);
    ++stats_.evictions;
    break;
  }

  // Miss: register a loading frame (it owns the slot from now on), then read without the lock.
  auto owned = std::make_unique<Frame>();
  Frame* frame = owned.get();
  frame->page = page;
  frame->pins = 1;
  table_.emplace(page, std::move(owned));
  ++stats_.misses;
  ++stats_.pinned_pages;
  stats_.peak_resident_bytes = std::max(stats_.peak_resident_bytes, table_.size() * page_bytes_);
  lock.unlock();

  Status status;
  bool read_failed = false;
  if (!buffer) buffer.reset(new (std::nothrow) std::byte[page_bytes_]);
  if (!buffer) {
    status = ResourceExhaustedError("page cache: out of memory allocating a page of " +
                                    std::to_string(page_bytes_) + " bytes");
  } else {
    status = store_->Read(page, {buffer.get(), page_bytes_});
    read_failed = !status.ok();
  }
  // A failed load frees its buffer before giving the slot back, so the budget holds.
  if (!status.ok()) buffer.reset();

  lock.lock();
  if (!status.ok()) {
    if (read_failed) ++stats_.failed_reads;
    table_.erase(page);
    --stats_.pinned_pages;
    state_cv_.notify_all();  // Waiters for this page retry the load themselves.
    room_cv_.notify_all();   // The slot is free again.
    return status;
  }
  frame->buffer = std::move(buffer);
  frame->loading = false;
  stats_.bytes_read += page_bytes_;
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

Status PageCache::Flush() {
  const auto deadline = std::chrono::steady_clock::now() + pin_timeout_;
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
      // Gone or clean: someone else (an evictor) wrote it back meanwhile.
      if (it == table_.end() || !it->second->dirty) break;
      Frame* frame = it->second.get();
      if (frame->writers > 0 || frame->writing) {
        // A holder may be modifying it, or another write is in flight: wait for either to end.
        if (std::chrono::steady_clock::now() >= deadline) {
          if (first_error.ok()) {
            first_error =
                ResourceExhaustedError("page cache flush: page " + std::to_string(page) +
                                       " stayed marked dirty by a live handle for " +
                                       std::to_string(pin_timeout_.count()) + " ms; not written");
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
  lock.unlock();
  // Sync even after a failed write: the pages that did reach the store become durable.
  Status sync = store_->Sync();
  if (!first_error.ok()) return first_error;
  return sync.ok() ? sync : sync.WithContext("page cache flush");
}

PageCacheStats PageCache::stats() const {
  std::lock_guard lock(mu_);
  Stats stats = stats_;
  stats.resident_bytes = table_.size() * page_bytes_;
  return stats;
}

void PageCache::Unpin(Frame* frame, bool marked_dirty) noexcept {
  std::lock_guard lock(mu_);
  if (marked_dirty) {
    --frame->writers;
    state_cv_.notify_all();  // Flush may be waiting for this writer.
  }
  if (--frame->pins == 0) {
    --stats_.pinned_pages;
    LruPushMruLocked(frame);
    room_cv_.notify_all();
  }
}

void PageCache::MarkDirty(Frame* frame) {
  std::unique_lock lock(mu_);
  // The in-flight write reads the buffer: modifications must wait until it is done.
  state_cv_.wait(lock, [frame] { return !frame->writing; });
  ++frame->writers;
  SetDirtyLocked(frame, true);
}

Status PageCache::WriteBackLocked(Frame* frame, std::unique_lock<std::mutex>& lock) {
  // `writing` keeps the frame and its buffer alive and unmodified while mu_ is released: no
  // evictor picks it, Flush waits for it, and MarkDirty() blocks until it is cleared.
  frame->writing = true;
  const uint64_t page = frame->page;
  const std::span<const std::byte> data(frame->buffer.get(), page_bytes_);
  lock.unlock();
  Status status = store_->Write(page, data);
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
  }
  state_cv_.notify_all();
  room_cv_.notify_all();
  return status;
}

PageCache::Frame* PageCache::PickVictimLocked() const {
  for (Frame* frame = lru_head_; frame != nullptr; frame = frame->lru_next) {
    if (!frame->writing) return frame;
  }
  return nullptr;
}

PageHandle PageCache::PinFrameLocked(Frame* frame) {
  if (frame->pins++ == 0) {
    LruRemoveLocked(frame);
    ++stats_.pinned_pages;
  }
  return PageHandle(this, frame, frame->page, frame->buffer.get(), page_bytes_);
}

void PageCache::LruPushMruLocked(Frame* frame) {
  frame->lru_prev = lru_tail_;
  frame->lru_next = nullptr;
  if (lru_tail_ != nullptr)
    lru_tail_->lru_next = frame;
  else
    lru_head_ = frame;
  lru_tail_ = frame;
  frame->in_lru = true;
}

void PageCache::LruRemoveLocked(Frame* frame) {
  if (!frame->in_lru) return;
  if (frame->lru_prev != nullptr)
    frame->lru_prev->lru_next = frame->lru_next;
  else
    lru_head_ = frame->lru_next;
  if (frame->lru_next != nullptr)
    frame->lru_next->lru_prev = frame->lru_prev;
  else
    lru_tail_ = frame->lru_prev;
  frame->lru_prev = frame->lru_next = nullptr;
  frame->in_lru = false;
}

void PageCache::SetDirtyLocked(Frame* frame, bool dirty) {
  if (frame->dirty == dirty) return;
  frame->dirty = dirty;
  if (dirty)
    ++stats_.dirty_pages;
  else
    --stats_.dirty_pages;
}

}  // namespace octoscope::paging
