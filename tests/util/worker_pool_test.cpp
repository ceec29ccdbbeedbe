#include "util/worker_pool.h"

#include <gtest/gtest.h>

#include <atomic>
#include <new>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

namespace octoscope {
namespace {

TEST(WorkerPoolTest, RunsEveryIterationOnceOnSeveralThreads) {
  for (int threads : {1, 2, 4}) {
    WorkerPool pool(threads);
    EXPECT_EQ(pool.threads(), threads);
    for (size_t n : {size_t{0}, size_t{1}, size_t{7}, size_t{1000}}) {
      std::vector<std::atomic<int>> runs(n);
      ASSERT_TRUE(pool.ParallelFor(n,
                                   [&](size_t i) {
                                     runs[i]++;
                                     return Status::Ok();
                                   })
                      .ok());
      for (size_t i = 0; i < n; ++i) EXPECT_EQ(runs[i].load(), 1) << i;
    }
  }
}

TEST(WorkerPoolTest, ReturnsTheFirstErrorByIndexAndSkipsTheRest) {
  WorkerPool pool(3);
  std::atomic<int> ran{0};
  Status s = pool.ParallelFor(10000, [&](size_t i) -> Status {
    ++ran;
    if (i == 5 || i == 7) return InvalidArgumentError("bad " + std::to_string(i));
    return Status::Ok();
  });
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("bad"), std::string::npos);
  EXPECT_LT(ran.load(), 10000);
  // The pool stays usable after an error.
  std::atomic<int> again{0};
  EXPECT_TRUE(pool.ParallelFor(50,
                               [&](size_t) {
                                 ++again;
                                 return Status::Ok();
                               })
                  .ok());
  EXPECT_EQ(again.load(), 50);
}

TEST(WorkerPoolTest, ExceptionsBecomeStatusesOnTheCallingThread) {
  WorkerPool pool(2);
  Status s = pool.ParallelFor(8, [&](size_t i) -> Status {
    if (i == 3) throw std::runtime_error("boom");
    return Status::Ok();
  });
  EXPECT_EQ(s.code(), StatusCode::kInternal);
  EXPECT_NE(s.message().find("boom"), std::string::npos);
  s = pool.ParallelFor(8, [&](size_t i) -> Status {
    if (i == 2) throw std::bad_alloc();
    return Status::Ok();
  });
  EXPECT_EQ(s.code(), StatusCode::kResourceExhausted);
}

TEST(WorkerPoolTest, UsesMoreThanOneThreadWhenItHasThem) {
  WorkerPool pool(2);
  std::mutex mu;
  std::set<std::thread::id> ids;
  std::atomic<int> arrived{0};
  // Two iterations that wait for each other can only finish when they run on two threads.
  Status s = pool.ParallelFor(2, [&](size_t) {
    {
      std::lock_guard lock(mu);
      ids.insert(std::this_thread::get_id());
    }
    ++arrived;
    for (int spin = 0; arrived.load() < 2 && spin < 2000000; ++spin) std::this_thread::yield();
    return Status::Ok();
  });
  EXPECT_TRUE(s.ok());
  EXPECT_EQ(ids.size(), 2u);
}

}  // namespace
}  // namespace octoscope
