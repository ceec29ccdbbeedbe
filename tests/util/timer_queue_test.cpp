#include "util/timer_queue.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <vector>

namespace octoscope {
namespace {

using std::chrono::milliseconds;

TEST(TimerQueueTest, RunsInTimeOrderNotBeforeTheirTime) {
  TimerQueue q;
  std::mutex mu;
  std::vector<int> order;
  std::atomic<int> done{0};
  const auto t0 = TimerQueue::Clock::now();
  std::vector<TimerQueue::Clock::time_point> ran(3);
  for (int i : {2, 0, 1}) {
    q.Schedule(t0 + milliseconds(20 + 20 * i), [&, i] {
      ran[i] = TimerQueue::Clock::now();
      std::lock_guard lock(mu);
      order.push_back(i);
      ++done;
    });
  }
  while (done.load() < 3) std::this_thread::sleep_for(milliseconds(1));
  EXPECT_EQ(order, (std::vector<int>{0, 1, 2}));
  for (int i = 0; i < 3; ++i) EXPECT_GE(ran[i], t0 + milliseconds(20 + 20 * i));
}

TEST(TimerQueueTest, CancelledTimersNeverRunAndExceptionsAreContained) {
  TimerQueue q;
  std::atomic<bool> ran{false}, after{false};
  const auto id = q.Schedule(TimerQueue::Clock::now() + milliseconds(50), [&] { ran = true; });
  EXPECT_TRUE(q.Cancel(id));
  EXPECT_FALSE(q.Cancel(id));
  q.Schedule(TimerQueue::Clock::now(), [] { throw std::runtime_error("x"); });
  q.Schedule(TimerQueue::Clock::now() + milliseconds(5), [&] { after = true; });
  while (!after) std::this_thread::sleep_for(milliseconds(1));
  std::this_thread::sleep_for(milliseconds(60));
  EXPECT_FALSE(ran.load());
}

TEST(TimerQueueTest, CallbacksMaySchedule) {
  TimerQueue q;
  std::atomic<int> n{0};
  std::function<void()> again = [&] {
    if (++n < 5) q.Schedule(TimerQueue::Clock::now(), again);
  };
  q.Schedule(TimerQueue::Clock::now(), again);
  while (n.load() < 5) std::this_thread::sleep_for(milliseconds(1));
  EXPECT_EQ(n.load(), 5);
}

}  // namespace
}  // namespace octoscope
