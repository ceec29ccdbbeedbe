#include "util/worker_pool.h"

#include <exception>
#include <new>
#include <string>
#include <system_error>

namespace octoscope {

WorkerPool::WorkerPool(int threads) {
  for (int t = 1; t < threads; ++t) {
    try {
      workers_.emplace_back([this] { WorkerMain(); });
    } catch (const std::system_error&) {
      break;  // Run with the threads we have.
    } catch (const std::bad_alloc&) {
      break;
    }
  }
}

WorkerPool::~WorkerPool() {
  {
    std::lock_guard lock(mu_);
    shutdown_ = true;
  }
  work_cv_.notify_all();
  for (std::thread& t : workers_) t.join();
}

void WorkerPool::RunIterations(std::unique_lock<std::mutex>& lock) {
  while (fn_ != nullptr && next_ < n_ && error_.ok()) {
    const size_t i = next_++;
    ++running_;
    const std::function<Status(size_t)>& fn = *fn_;
    lock.unlock();
    Status s;
    try {
      s = fn(i);
    } catch (const std::bad_alloc&) {
      s = ResourceExhaustedError("out of memory in a parallel loop");
    } catch (const std::exception& e) {
      s = InternalError(std::string("exception in a parallel loop: ") + e.what());
    }
    lock.lock();
    if (!s.ok() && (error_.ok() || i < error_index_)) {
      error_ = std::move(s);
      error_index_ = i;
    }
    if (--running_ == 0 && (next_ >= n_ || !error_.ok())) done_cv_.notify_all();
  }
}

void WorkerPool::WorkerMain() {
  std::unique_lock lock(mu_);
  uint64_t seen = 0;
  for (;;) {
    work_cv_.wait(lock, [&] { return shutdown_ || (fn_ != nullptr && loop_id_ != seen); });
    if (shutdown_) return;
    seen = loop_id_;
    RunIterations(lock);
  }
}

Status WorkerPool::ParallelFor(size_t n, const std::function<Status(size_t)>& fn) {
  if (n == 0) return Status::Ok();
  std::lock_guard loop_lock(loop_mu_);
  std::unique_lock lock(mu_);
  fn_ = &fn;
  n_ = n;
  next_ = 0;
  running_ = 0;
  error_ = Status::Ok();
  error_index_ = 0;
  ++loop_id_;
  if (!workers_.empty() && n > 1) work_cv_.notify_all();
  RunIterations(lock);
  done_cv_.wait(lock, [&] { return running_ == 0; });
  fn_ = nullptr;
  return std::move(error_);
}

}  // namespace octoscope
