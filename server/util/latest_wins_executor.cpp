#include "util/latest_wins_executor.h"

#include <exception>
#include <system_error>

namespace octoscope {

LatestWinsExecutor::LatestWinsExecutor(int threads) {
  for (int t = 0; t < std::max(1, threads); ++t) {
    try {
      workers_.emplace_back([this] { WorkerMain(); });
    } catch (const std::system_error&) {
      break;
    }
  }
}

LatestWinsExecutor::~LatestWinsExecutor() {
  {
    std::lock_guard lock(mu_);
    shutdown_ = true;
    pending_.clear();
    order_.clear();
  }
  cv_.notify_all();
  for (std::thread& t : workers_) t.join();
}

void LatestWinsExecutor::Submit(uint64_t key, std::function<void()> job) {
  {
    std::lock_guard lock(mu_);
    if (shutdown_) return;
    auto [it, inserted] = pending_.try_emplace(key);
    if (!inserted) {
      ++replaced_;
    } else {
      order_.push_back(key);
    }
    it->second = std::move(job);
  }
  cv_.notify_one();
}

void LatestWinsExecutor::Post(std::function<void()> job) {
  uint64_t key;
  {
    std::lock_guard lock(mu_);
    key = next_post_key_++;
    if (next_post_key_ == 0) next_post_key_ = kFirstPostKey;
  }
  Submit(key, std::move(job));
}

void LatestWinsExecutor::Forget(uint64_t key) {
  std::lock_guard lock(mu_);
  pending_.erase(key);  // Its entry in order_ is skipped when reached.
}

void LatestWinsExecutor::Wait(uint64_t key) {
  std::unique_lock lock(mu_);
  idle_cv_.wait(lock, [&] { return !pending_.count(key) && !running_.count(key); });
}

uint64_t LatestWinsExecutor::replaced() const {
  std::lock_guard lock(mu_);
  return replaced_;
}

uint64_t LatestWinsExecutor::failures() const {
  std::lock_guard lock(mu_);
  return failures_;
}

void LatestWinsExecutor::WorkerMain() {
  std::unique_lock lock(mu_);
  for (;;) {
    // The oldest key with a pending job that is not running now.
    std::function<void()> job;
    uint64_t key = 0;
    for (auto it = order_.begin(); it != order_.end();) {
      if (!pending_.count(*it)) {
        it = order_.erase(it);  // Forgotten.
        continue;
      }
      if (running_.count(*it)) {
        ++it;
        continue;
      }
      key = *it;
      order_.erase(it);
      auto p = pending_.find(key);
      job = std::move(p->second);
      pending_.erase(p);
      break;
    }
    if (!job) {
      if (shutdown_) return;
      cv_.wait(lock);
      continue;
    }
    running_.insert(key);
    lock.unlock();
    bool failed = false;
    try {
      job();
    } catch (...) {
      failed = true;
    }
    job = nullptr;  // Destroy captures outside the lock too.
    lock.lock();
    if (failed) ++failures_;
    running_.erase(key);
    // A job of this key submitted while it ran may now run.
    if (pending_.count(key)) cv_.notify_one();
    idle_cv_.notify_all();
  }
}

}  // namespace octoscope
