#include "net/auth.h"

#include <gtest/gtest.h>

#include <string>

namespace octoscope::net {
namespace {

TEST(AuthTest, ConstantTimeEqualsComparesWholeStrings) {
  EXPECT_TRUE(ConstantTimeEquals("", ""));
  EXPECT_TRUE(ConstantTimeEquals("abc", "abc"));
  EXPECT_FALSE(ConstantTimeEquals("abc", "abd"));
  EXPECT_FALSE(ConstantTimeEquals("xbc", "abc"));
  EXPECT_FALSE(ConstantTimeEquals("ab", "abc"));
  EXPECT_FALSE(ConstantTimeEquals("abcd", "abc"));
  EXPECT_FALSE(ConstantTimeEquals("", "abc"));
  EXPECT_FALSE(ConstantTimeEquals("abc", ""));
  // Bytes beyond ASCII and embedded NULs are compared like any other.
  EXPECT_FALSE(ConstantTimeEquals(std::string("a\0c", 3), std::string("a\0d", 3)));
  EXPECT_TRUE(ConstantTimeEquals(std::string("a\0\xff", 3), std::string("a\0\xff", 3)));
  // A prefix of the secret padded with NULs is not the secret.
  EXPECT_FALSE(ConstantTimeEquals(std::string("ab\0", 3), "abc"));
}

TEST(AuthTest, TokenFromBearerHeaderOrQuery) {
  const std::string token = "0123456789abcdef0123456789abcdef";
  EXPECT_TRUE(RequestCarriesToken(token, "Bearer " + token, ""));
  EXPECT_TRUE(RequestCarriesToken(token, "bearer " + token, ""));
  EXPECT_TRUE(RequestCarriesToken(token, "BEARER   " + token + "  ", ""));
  EXPECT_TRUE(RequestCarriesToken(token, "", "token=" + token));
  EXPECT_TRUE(RequestCarriesToken(token, "", "a=1&token=" + token + "&b=2"));
  // Percent-encoded token characters are decoded.
  EXPECT_TRUE(RequestCarriesToken("a b+c", "", "token=a%20b%2Bc"));
  // Either place may hold it.
  EXPECT_TRUE(RequestCarriesToken(token, "Bearer wrong", "token=" + token));
  EXPECT_TRUE(RequestCarriesToken(token, "Bearer " + token, "token=wrong"));

  EXPECT_FALSE(RequestCarriesToken(token, "", ""));
  EXPECT_FALSE(RequestCarriesToken(token, token, ""));  // No scheme.
  EXPECT_FALSE(RequestCarriesToken(token, "Basic " + token, ""));
  EXPECT_FALSE(RequestCarriesToken(token, "Bearer", ""));
  EXPECT_FALSE(RequestCarriesToken(token, "Bearer " + token.substr(1), ""));
  EXPECT_FALSE(RequestCarriesToken(token, "", "token=" + token + "x"));
  EXPECT_FALSE(RequestCarriesToken(token, "", "xtoken=" + token));
  EXPECT_FALSE(RequestCarriesToken(token, "", "token"));
  EXPECT_FALSE(RequestCarriesToken(token, "", "token=%zz"));
}

}  // namespace
}  // namespace octoscope::net
