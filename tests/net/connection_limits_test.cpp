// ConnectionLimits: places in all and per address are taken and given back (also moved and from
// many threads), and refusals are reported at most once a second.
#include "net/connection_limits.h"

#include <gtest/gtest.h>

#include <thread>
#include <utility>
#include <vector>

namespace octoscope::net::detail {
namespace {

TEST(ConnectionLimitsTest, PlacesAreTakenAndGivenBack) {
  ConnectionLimits limits(3, 2);
  std::vector<ConnectionLimits::Slot> all;
  for (int i = 0; i < 3; ++i) {
    auto slot = limits.AcquireTotal();
    ASSERT_TRUE(slot.has_value());
    all.push_back(std::move(*slot));
  }
  EXPECT_FALSE(limits.AcquireTotal().has_value());
  EXPECT_EQ(limits.total(), 3u);
  all.pop_back();
  EXPECT_EQ(limits.total(), 2u);
  EXPECT_TRUE(limits.AcquireTotal().has_value());  // Taken and given back at once.

  auto a1 = limits.AcquireAddress("203.0.113.7");
  auto a2 = limits.AcquireAddress("203.0.113.7");
  ASSERT_TRUE(a1 && a2);
  EXPECT_FALSE(limits.AcquireAddress("203.0.113.7").has_value());
  EXPECT_TRUE(limits.AcquireAddress("198.51.100.9").has_value());
  EXPECT_EQ(limits.count("203.0.113.7"), 2u);
  EXPECT_EQ(limits.total(), 2u);  // Address places are not places in all.
  ConnectionLimits::Slot moved = std::move(*a1);
  a1.reset();
  EXPECT_EQ(limits.count("203.0.113.7"), 2u);
  EXPECT_TRUE(moved.held());
  EXPECT_EQ(moved.address(), "203.0.113.7");
  moved.reset();
  moved.reset();
  EXPECT_EQ(limits.count("203.0.113.7"), 1u);
  moved = std::move(*a2);
  moved = ConnectionLimits::Slot();
  EXPECT_EQ(limits.count("203.0.113.7"), 0u);
}

TEST(ConnectionLimitsTest, ManyThreadsNeverPassTheCaps) {
  ConnectionLimits limits(8, 3);
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < 5000; ++i) {
        auto total = limits.AcquireTotal();
        auto address = limits.AcquireAddress(t % 2 ? "a" : "b");
        EXPECT_LE(limits.total(), 8u);
        EXPECT_LE(limits.count("a"), 3u);
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(limits.total(), 0u);
  EXPECT_EQ(limits.count("a"), 0u);
}

TEST(ConnectionLimitsTest, RefusalsAreReportedAtMostOnceASecond) {
  ConnectionLimits limits(1, 1);
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(limits.CountRefusal(t0), 1u);
  EXPECT_EQ(limits.CountRefusal(t0 + std::chrono::milliseconds(10)), 0u);
  EXPECT_EQ(limits.CountRefusal(t0 + std::chrono::milliseconds(500)), 0u);
  EXPECT_EQ(limits.CountRefusal(t0 + std::chrono::milliseconds(1001)), 3u);
  EXPECT_EQ(limits.CountRefusal(t0 + std::chrono::milliseconds(1002)), 0u);
}

}  // namespace
}  // namespace octoscope::net::detail
