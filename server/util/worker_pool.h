// WorkerPool: a fixed set of threads that run the iterations of a parallel loop together with
// the calling thread (fork-join). Used where one operation has independent pieces of work — the
// bricks one octree insert writes, for instance — so that it finishes on all cores.
//
// Errors: each iteration returns a Status; ParallelFor returns the first non-OK one (by
// iteration index) after every started iteration has finished; iterations not yet started when
// an error is seen are skipped. An exception thrown by an iteration never crosses a thread: it is
// caught and reported as a Status (kResourceExhausted for std::bad_alloc, else kInternal).
// A pool whose worker threads could not be started (e.g. the process hit its thread limit) runs
// every loop on the calling thread alone: fewer threads, never a failure.
//
// Thread safety: ParallelFor may be called from one thread at a time (a second caller waits for
// the first loop to finish). The destructor joins every worker; it must not run concurrently with
// ParallelFor.
#ifndef OCTOSCOPE_UTIL_WORKER_POOL_H_
#define OCTOSCOPE_UTIL_WORKER_POOL_H_

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include "util/status.h"

namespace octoscope {

class WorkerPool {
 public:
  // A pool that runs loops on `threads` threads in all: threads - 1 workers plus the caller.
  // threads <= 1 gives a pool without workers.
  explicit WorkerPool(int threads);
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  // Runs fn(i) for every i in [0, n), spread over the workers and the caller, and returns when
  // all have finished. See the header comment for errors.
  Status ParallelFor(size_t n, const std::function<Status(size_t)>& fn);

  // Threads a loop runs on (workers actually started + the caller).
  int threads() const { return static_cast<int>(workers_.size()) + 1; }

 private:
  // Runs iterations of the current loop until none is left. REQUIRES: lock holds mu_.
  void RunIterations(std::unique_lock<std::mutex>& lock);
  void WorkerMain();

  std::mutex loop_mu_;  // Serialises ParallelFor callers.
  std::mutex mu_;
  std::condition_variable work_cv_;  // A loop started, or shutdown.
  std::condition_variable done_cv_;  // The last iteration of a loop finished.
  // The current loop (guarded by mu_).
  const std::function<Status(size_t)>* fn_ = nullptr;
  size_t n_ = 0;
  size_t next_ = 0;     // Next iteration to hand out.
  size_t running_ = 0;  // Iterations started and not finished.
  uint64_t loop_id_ = 0;
  size_t error_index_ = 0;
  Status error_;
  bool shutdown_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_WORKER_POOL_H_
