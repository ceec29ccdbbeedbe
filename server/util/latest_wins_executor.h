// LatestWinsExecutor: a small pool of threads for work where only the newest job of a kind
// matters — encoding the newest rendered image of a view, for instance. Jobs are submitted under
// a key; a key has at most one PENDING job (a newer Submit replaces it, and the replaced job is
// never run) and its jobs never run concurrently, so they finish in submission order. Different
// keys run in parallel, oldest pending first.
//
// Exceptions thrown by a job are caught on the worker (counted in failures()); they never cross
// threads. The destructor drops pending jobs and joins the workers after their running jobs.
//
// Thread safety: Submit, Forget and the counters are thread-safe and may be called from jobs.
#ifndef OCTOSCOPE_UTIL_LATEST_WINS_EXECUTOR_H_
#define OCTOSCOPE_UTIL_LATEST_WINS_EXECUTOR_H_

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <set>
#include <thread>
#include <unordered_map>
#include <vector>

namespace octoscope {

class LatestWinsExecutor {
 public:
  explicit LatestWinsExecutor(int threads);
  ~LatestWinsExecutor();
  LatestWinsExecutor(const LatestWinsExecutor&) = delete;
  LatestWinsExecutor& operator=(const LatestWinsExecutor&) = delete;

  // REQUIRES: key < kFirstPostKey.
  void Submit(uint64_t key, std::function<void()> job);
  // A job that is never replaced (durable writes, requests that each want an answer): it runs
  // under a key of its own from the range [kFirstPostKey, 2^64).
  void Post(std::function<void()> job);
  static constexpr uint64_t kFirstPostKey = uint64_t{1} << 63;
  // Drops the key's pending job (a running one finishes).
  void Forget(uint64_t key);
  // Returns when no job of `key` is pending or running.
  void Wait(uint64_t key);

  uint64_t replaced() const;  // Pending jobs replaced by newer ones.
  uint64_t failures() const;  // Jobs that threw.

 private:
  void WorkerMain();

  mutable std::mutex mu_;
  std::condition_variable cv_;       // Work or shutdown.
  std::condition_variable idle_cv_;  // A job finished.
  std::unordered_map<uint64_t, std::function<void()>> pending_;
  std::deque<uint64_t> order_;  // Keys with a pending job, oldest first (may hold stale keys).
  std::set<uint64_t> running_;
  bool shutdown_ = false;
  uint64_t replaced_ = 0;
  uint64_t failures_ = 0;
  uint64_t next_post_key_ = kFirstPostKey;
  std::vector<std::thread> workers_;
};

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_LATEST_WINS_EXECUTOR_H_
