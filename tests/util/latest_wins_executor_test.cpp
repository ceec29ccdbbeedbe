#include "util/latest_wins_executor.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <vector>

namespace octoscope {
namespace {

TEST(LatestWinsExecutorTest, APendingJobIsReplacedAndAKeyNeverRunsConcurrently) {
  LatestWinsExecutor ex(2);
  std::atomic<bool> release{false};
  std::atomic<int> running{0}, max_running{0};
  std::mutex mu;
  std::vector<int> ran;
  auto job = [&](int n) {
    return [&, n] {
      const int r = ++running;
      int m = max_running.load();
      while (r > m && !max_running.compare_exchange_weak(m, r)) {
      }
      while (n == 0 && !release) std::this_thread::yield();
      {
        std::lock_guard lock(mu);
        ran.push_back(n);
      }
      --running;
    };
  };
  ex.Submit(7, job(0));  // Blocks until released.
  while (running.load() == 0) std::this_thread::yield();
  for (int n = 1; n <= 50; ++n) ex.Submit(7, job(n));  // Only the last survives.
  release = true;
  ex.Wait(7);
  EXPECT_EQ(ran, (std::vector<int>{0, 50}));
  EXPECT_EQ(max_running.load(), 1);
  EXPECT_EQ(ex.replaced(), 49u);
}

TEST(LatestWinsExecutorTest, PostedJobsAreNeverReplaced) {
  LatestWinsExecutor ex(1);
  std::atomic<bool> release{false};
  std::atomic<int> ran{0};
  ex.Post([&] {
    while (!release) std::this_thread::yield();
    ++ran;
  });
  for (int i = 0; i < 20; ++i) ex.Post([&] { ++ran; });
  release = true;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (ran.load() < 21 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::yield();
  }
  EXPECT_EQ(ran.load(), 21);
  EXPECT_EQ(ex.replaced(), 0u);
}

TEST(LatestWinsExecutorTest, KeysRunInParallelAndExceptionsAreContained) {
  LatestWinsExecutor ex(2);
  std::atomic<int> arrived{0};
  auto meet = [&] {
    ++arrived;
    for (int i = 0; arrived.load() < 2 && i < 2000000; ++i) std::this_thread::yield();
  };
  ex.Submit(1, meet);
  ex.Submit(2, meet);
  ex.Wait(1);
  ex.Wait(2);
  EXPECT_EQ(arrived.load(), 2);
  ex.Submit(3, [] { throw std::runtime_error("x"); });
  ex.Wait(3);
  EXPECT_EQ(ex.failures(), 1u);
  std::atomic<bool> ran{false};
  ex.Submit(3, [&] { ran = true; });
  ex.Wait(3);
  EXPECT_TRUE(ran.load());
}

TEST(LatestWinsExecutorTest, ForgetDropsThePendingJobAndDestructionJoins) {
  std::atomic<int> count{0};
  {
    LatestWinsExecutor ex(1);
    std::atomic<bool> release{false};
    ex.Submit(1, [&] {
      while (!release) std::this_thread::yield();
      ++count;
    });
    while (count.load() == 0 && !release) {
      ex.Submit(2, [&] { count += 100; });
      ex.Forget(2);
      release = true;
    }
    ex.Wait(1);
    ex.Submit(3, [&] { ++count; });
  }
  EXPECT_TRUE(count.load() == 1 || count.load() == 2);  // Job 3 may or may not have run.
}

}  // namespace
}  // namespace octoscope
