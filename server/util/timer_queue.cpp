#include "util/timer_queue.h"

namespace octoscope {

TimerQueue::TimerQueue() : thread_([this] { Main(); }) {}

TimerQueue::~TimerQueue() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
    timers_.clear();
    index_.clear();
  }
  cv_.notify_all();
  thread_.join();
}

TimerQueue::TimerId TimerQueue::Schedule(Clock::time_point when, std::function<void()> fn) {
  std::lock_guard lock(mu_);
  const TimerId id = next_id_++;
  if (stop_) return id;
  timers_.emplace(when, std::make_pair(id, std::move(fn)));
  index_.emplace(id, when);
  cv_.notify_all();
  return id;
}

bool TimerQueue::Cancel(TimerId id) {
  std::lock_guard lock(mu_);
  auto it = index_.find(id);
  if (it == index_.end()) return false;
  auto [lo, hi] = timers_.equal_range(it->second);
  for (auto t = lo; t != hi; ++t) {
    if (t->second.first == id) {
      timers_.erase(t);
      break;
    }
  }
  index_.erase(it);
  return true;
}

size_t TimerQueue::pending() const {
  std::lock_guard lock(mu_);
  return timers_.size();
}

void TimerQueue::Main() {
  std::unique_lock lock(mu_);
  while (!stop_) {
    if (timers_.empty()) {
      cv_.wait(lock);
      continue;
    }
    const auto due = timers_.begin()->first;
    if (Clock::now() < due) {
      cv_.wait_until(lock, due);
      continue;
    }
    auto node = timers_.extract(timers_.begin());
    index_.erase(node.mapped().first);
    std::function<void()> fn = std::move(node.mapped().second);
    lock.unlock();
    try {
      fn();
    } catch (...) {
    }
    fn = nullptr;
    lock.lock();
  }
}

}  // namespace octoscope
