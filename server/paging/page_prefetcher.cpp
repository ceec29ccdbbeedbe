#include "paging/page_prefetcher.h"

#include <algorithm>
#include <exception>
#include <string>
#include <utility>

namespace octoscope::paging {
namespace {

using Clock = std::chrono::steady_clock;

PagePrefetcherOptions Sanitized(PagePrefetcherOptions options) {
  options.io_threads = std::clamp(options.io_threads, 1, 64);
  options.max_outstanding = std::max<size_t>(options.max_outstanding, 1);
  options.room_timeout = std::max(options.room_timeout, std::chrono::milliseconds{0});
  options.failure_hold = std::max(options.failure_hold, std::chrono::milliseconds{0});
  return options;
}

}  // namespace

size_t PagePrefetcher::KeyHash::operator()(const Key& key) const noexcept {
  const size_t a = std::hash<const void*>()(key.cache);
  const size_t b = std::hash<uint64_t>()(key.page);
  return a ^ (b + 0x9E3779B97F4A7C15ull + (a << 6) + (a >> 2));
}

PagePrefetcher::PagePrefetcher(PagePrefetcherOptions options)
    : options_(Sanitized(std::move(options))) {
  threads_.reserve(static_cast<size_t>(options_.io_threads));
  try {
    for (int i = 0; i < options_.io_threads; ++i) threads_.emplace_back([this] { IoLoop(); });
  } catch (...) {
    // Join the threads already started before the exception leaves the constructor.
    {
      std::lock_guard lock(mu_);
      stop_ = true;
    }
    work_cv_.notify_all();
    for (auto& t : threads_) t.join();
    throw;
  }
}

PagePrefetcher::~PagePrefetcher() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
    // Queued requests end without a completion; loads in flight finish (bounded) unreported.
    stats_.cancelled += queue_.size();
    for (const Key& key : queue_) entries_.erase(key);
    queue_.clear();
  }
  work_cv_.notify_all();
  completion_cv_.notify_all();
  for (auto& t : threads_) t.join();
}

PrefetchRequestResult PagePrefetcher::Request(PageCache* cache, uint64_t page) {
  // Outside our lock: the cache's lock is never taken while holding ours.
  const bool resident = cache->IsResident(page);
  const auto now = Clock::now();
  std::lock_guard lock(mu_);
  if (stop_) {
    ++stats_.refused;
    return PrefetchRequestResult::kShutDown;
  }
  if (resident) {
    ++stats_.resident;
    return PrefetchRequestResult::kResident;
  }
  const Key key{cache, page};
  CacheState& state = caches_[cache];
  if (auto it = entries_.find(key); it != entries_.end()) {
    // Requested again: a load in flight that was cancelled reports its completion after all.
    it->second.epoch = state.epoch;
    ++stats_.duplicates;
    return PrefetchRequestResult::kDuplicate;
  }
  if (RecentlyFailedLocked(key, now)) {
    ++stats_.refused;
    return PrefetchRequestResult::kRecentlyFailed;
  }
  if (OutstandingLocked() >= options_.max_outstanding) {
    ++stats_.refused;
    return PrefetchRequestResult::kQueueFull;
  }
  entries_.emplace(key, Entry{.in_flight = false, .epoch = state.epoch});
  queue_.push_back(key);
  ++stats_.accepted;
  work_cv_.notify_one();
  return PrefetchRequestResult::kQueued;
}

size_t PagePrefetcher::CancelAll(PageCache* cache) {
  std::lock_guard lock(mu_);
  return CancelLocked(cache);
}

size_t PagePrefetcher::CancelAll() {
  std::lock_guard lock(mu_);
  return CancelLocked(nullptr);
}

size_t PagePrefetcher::CancelLocked(PageCache* cache) {
  auto matches = [cache](PageCache* c) { return cache == nullptr || c == cache; };
  size_t count = 0;
  // Queued requests: dropped now.
  std::erase_if(queue_, [&](const Key& key) {
    if (!matches(key.cache)) return false;
    entries_.erase(key);
    ++count;
    return true;
  });
  stats_.cancelled += count;
  // Loads in flight: their completions are suppressed by the epoch bump (counted when they end).
  for (const auto& [key, entry] : entries_) {
    if (entry.in_flight && matches(key.cache) && entry.epoch == caches_[key.cache].epoch) ++count;
  }
  for (auto& [c, state] : caches_) {
    if (matches(c)) ++state.epoch;
  }
  return count;
}

void PagePrefetcher::Detach(PageCache* cache) {
  std::unique_lock lock(mu_);
  CancelLocked(cache);
  idle_cv_.wait(lock, [&] {
    auto it = caches_.find(cache);
    return it == caches_.end() || it->second.busy == 0;
  });
  caches_.erase(cache);
  std::erase_if(failures_, [cache](const auto& item) { return item.first.cache == cache; });
}

bool PagePrefetcher::WaitForCompletion(std::chrono::milliseconds timeout) {
  std::unique_lock lock(mu_);
  completion_cv_.wait_for(lock, timeout, [this] { return !completions_.empty() || stop_; });
  return !completions_.empty();
}

std::vector<PrefetchCompletion> PagePrefetcher::TakeCompletions() {
  std::lock_guard lock(mu_);
  return std::exchange(completions_, {});
}

PagePrefetcherStats PagePrefetcher::stats() const {
  std::lock_guard lock(mu_);
  Stats stats = stats_;
  stats.queued = queue_.size();
  stats.in_flight = in_flight_;
  return stats;
}

bool PagePrefetcher::RecentlyFailedLocked(const Key& key, Clock::time_point now) {
  auto it = failures_.find(key);
  if (it == failures_.end()) return false;
  if (now - it->second < options_.failure_hold) return true;
  failures_.erase(it);  // Expired: may be tried again.
  return false;
}

void PagePrefetcher::RememberFailureLocked(const Key& key, Clock::time_point now) {
  // Bounded: a badly damaged store must not make this map grow without limit.
  const size_t cap = std::max<size_t>(1024, options_.max_outstanding);
  if (failures_.size() >= cap) {
    std::erase_if(failures_,
                  [&](const auto& item) { return now - item.second >= options_.failure_hold; });
    if (failures_.size() >= cap) failures_.erase(failures_.begin());
  }
  failures_[key] = now;
}

void PagePrefetcher::IoLoop() noexcept {
  std::unique_lock lock(mu_);
  for (;;) {
    work_cv_.wait(lock, [this] { return stop_ || !queue_.empty(); });
    if (stop_) return;
    ServeOne(lock);
  }
}

void PagePrefetcher::ServeOne(std::unique_lock<std::mutex>& lock) {
  const Key key = queue_.front();
  queue_.pop_front();
  entries_[key].in_flight = true;
  CacheState& state = caches_[key.cache];  // Stable: Detach waits for busy == 0 to erase it.
  ++state.busy;
  ++in_flight_;
  lock.unlock();

  bool read_failed = false;
  Status status;
  try {
    status = key.cache->Prefetch(key.page, options_.room_timeout, &read_failed);
  } catch (...) {
    status = Status(StatusCode::kInternal, "page prefetch threw");
  }

  lock.lock();
  try {
    auto it = entries_.find(key);
    const bool cancelled = stop_ || it == entries_.end() || it->second.epoch != state.epoch;
    if (it != entries_.end()) entries_.erase(it);
    if (cancelled) {
      ++stats_.cancelled;
    } else {
      if (status.ok()) {
        ++stats_.loaded;
      } else if (status.code() == StatusCode::kResourceExhausted) {
        ++stats_.no_room;
      } else {
        ++stats_.failed;
      }
      if (read_failed) RememberFailureLocked(key, Clock::now());
      PrefetchCompletion completion{key.cache, key.page, std::move(status)};
      if (options_.on_complete) {
        lock.unlock();
        try {
          options_.on_complete(completion);
        } catch (...) {
          // Documented: an exception from the callback is dropped (it must not kill the thread).
        }
        lock.lock();
      } else {
        completions_.push_back(std::move(completion));
        completion_cv_.notify_all();
      }
    }
  } catch (...) {
    // Out of memory recording the completion: it is lost, the bookkeeping below still runs.
    if (!lock.owns_lock()) lock.lock();
    entries_.erase(key);
  }
  --state.busy;
  --in_flight_;
  idle_cv_.notify_all();
}

}  // namespace octoscope::paging
