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

TEST(AuthTest, ReadCredentialsFindsTokensSharesAndViews) {
  RequestCredentials c = ReadCredentials("Bearer abc", "token=d%20e&share=s1&share=s2&view=v1");
  ASSERT_EQ(c.tokens.size(), 2u);
  EXPECT_EQ(c.tokens[0], "abc");
  EXPECT_EQ(c.tokens[1], "d e");
  EXPECT_EQ(c.share, "s1");
  EXPECT_EQ(c.view, "v1");
  // A malformed query carries nothing (the header still counts).
  c = ReadCredentials("Bearer abc", "share=%zz");
  EXPECT_EQ(c.tokens.size(), 1u);
  EXPECT_FALSE(c.share.has_value());
  EXPECT_EQ(StripCredentials("a=1&token=x&share=y&view=z&b=2"), "a=1&b=2");
  EXPECT_EQ(StripCredentials("token=x"), "");
}

TEST(AuthTest, TokenAuthenticatorAdmitsItsTokenAsAnAdmin) {
  TokenAuthenticator auth("0123456789abcdef");
  std::optional<Principal> p = auth.Authenticate("", "token=0123456789abcdef");
  ASSERT_TRUE(p.has_value());
  EXPECT_EQ(p->kind, Principal::Kind::kUser);
  EXPECT_EQ(p->user, "admin");
  EXPECT_TRUE(p->admin);
  EXPECT_FALSE(auth.Authenticate("", "share=0123456789abcdef").has_value());
  EXPECT_FALSE(auth.Authenticate("Bearer 0123456789abcdeF", "").has_value());
  EXPECT_EQ(auth.RefusalMessage("", ""), "missing or wrong token");
}

}  // namespace
}  // namespace octoscope::net
