// TimerQueue: one thread that runs callbacks at given times — e.g. a viewing session's "refine
// 200 ms after the last change". Callbacks run on the queue's thread, one at a time, and must be
// quick (hand real work to another thread). Exceptions thrown by callbacks are caught and
// dropped; they never cross threads.
//
// Thread safety: Schedule and Cancel are thread-safe and may be called from callbacks. The
// destructor drops pending timers and joins the thread (after a running callback).
#ifndef OCTOSCOPE_UTIL_TIMER_QUEUE_H_
#define OCTOSCOPE_UTIL_TIMER_QUEUE_H_

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <thread>
#include <utility>

namespace octoscope {

class TimerQueue {
 public:
  using Clock = std::chrono::steady_clock;
  using TimerId = uint64_t;

  TimerQueue();
  ~TimerQueue();
  TimerQueue(const TimerQueue&) = delete;
  TimerQueue& operator=(const TimerQueue&) = delete;

  // Runs `fn` at `when` (at once when it has passed). Returns an id for Cancel.
  TimerId Schedule(Clock::time_point when, std::function<void()> fn);
  // Drops the timer if it has not started; false when it already ran, runs or never existed.
  bool Cancel(TimerId id);
  size_t pending() const;

 private:
  void Main();

  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::multimap<Clock::time_point, std::pair<TimerId, std::function<void()>>> timers_;
  std::map<TimerId, Clock::time_point> index_;
  TimerId next_id_ = 1;
  bool stop_ = false;
  std::thread thread_;  // Last: started when the rest exists.
};

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_TIMER_QUEUE_H_
