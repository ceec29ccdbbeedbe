#include "util/random_token.h"

#include <gtest/gtest.h>

#include <set>

namespace octoscope {
namespace {

TEST(RandomTokenTest, HexOfTheRequestedLengthAndNeverRepeated) {
  std::set<std::string> seen;
  for (int i = 0; i < 1000; ++i) {
    auto token = RandomHex(16);
    ASSERT_TRUE(token.ok());
    ASSERT_EQ(token->size(), 32u);
    EXPECT_EQ(token->find_first_not_of("0123456789abcdef"), std::string::npos);
    EXPECT_TRUE(seen.insert(*token).second);
  }
}

TEST(RandomTokenTest, EveryNibbleValueAppears) {
  auto token = RandomHex(256);
  ASSERT_TRUE(token.ok());
  std::set<char> digits(token->begin(), token->end());
  EXPECT_EQ(digits.size(), 16u);  // 512 digits miss one of 16 values with p < 1e-13.
}

}  // namespace
}  // namespace octoscope
