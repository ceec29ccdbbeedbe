#include "util/token_bucket.h"

#include <gtest/gtest.h>

namespace octoscope {
namespace {

using std::chrono::milliseconds;

TEST(TokenBucketTest, BurstThenRate) {
  const auto t0 = TokenBucket::Clock::now();
  TokenBucket bucket(10, 3);  // 10 per second, bursts of 3.
  EXPECT_TRUE(bucket.Take(t0));
  EXPECT_TRUE(bucket.Take(t0));
  EXPECT_TRUE(bucket.Take(t0));
  EXPECT_FALSE(bucket.Take(t0));
  // 100 ms later one token came back, not more.
  EXPECT_FALSE(bucket.Take(t0 + milliseconds(50)));
  EXPECT_TRUE(bucket.Take(t0 + milliseconds(100)));
  EXPECT_FALSE(bucket.Take(t0 + milliseconds(110)));
  // A long pause refills up to the burst only.
  const auto later = t0 + milliseconds(10'000);
  EXPECT_DOUBLE_EQ(bucket.Available(later), 3);
  int taken = 0;
  while (bucket.Take(later)) ++taken;
  EXPECT_EQ(taken, 3);
}

TEST(TokenBucketTest, RateZeroAdmitsTheBurstInAll) {
  const auto t0 = TokenBucket::Clock::now();
  TokenBucket bucket(0, 2);
  EXPECT_TRUE(bucket.Take(t0));
  EXPECT_TRUE(bucket.Take(t0 + milliseconds(1)));
  EXPECT_FALSE(bucket.Take(t0 + milliseconds(100'000)));
}

TEST(TokenBucketTest, TimeGoingBackwardsGivesNothing) {
  const auto t0 = TokenBucket::Clock::now();
  TokenBucket bucket(1000, 1);
  EXPECT_TRUE(bucket.Take(t0 + milliseconds(10)));
  EXPECT_FALSE(bucket.Take(t0));
}

}  // namespace
}  // namespace octoscope
