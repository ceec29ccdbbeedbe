// OriginPolicy: parsing origins and URLs, matching by scheme, host and port (default ports,
// case, loopback names), the listener's own origin and a forwarded one.
#include "net/origin_policy.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace octoscope::net {
namespace {

namespace ip = boost::asio::ip;

TEST(OriginPolicyTest, ParsesOriginsAndTheOriginsOfUrls) {
  struct Case {
    const char* text;
    const char* origin;  // ToString(); nullptr: refused.
  };
  const std::vector<Case> cases = {
      {"https://scope.lab.example", "https://scope.lab.example"},
      {"https://Scope.LAB.example:443/", "https://scope.lab.example"},
      {"HTTP://scope.lab.example:80", "http://scope.lab.example"},
      {"https://scope.lab.example:8443/octoscope/", "https://scope.lab.example:8443"},
      {"http://127.0.0.1:8080", "http://127.0.0.1:8080"},
      {"http://[::1]:8080", "http://[::1]:8080"},
      {"http://[FD00::1]", "http://[fd00::1]"},
      {" https://a.example ", "https://a.example"},
      {"null", nullptr},
      {"", nullptr},
      {"scope.lab.example", nullptr},
      {"ftp://scope.lab.example", nullptr},
      {"https://", nullptr},
      {"https://:443", nullptr},
      {"https://a.example:0", nullptr},
      {"https://a.example:65536", nullptr},
      {"https://a.example:", nullptr},
      {"https://a.example:+1", nullptr},
      {"https://a.example?x=1", nullptr},
      {"https://a.example#x", nullptr},
      {"https://user@a.example", nullptr},
      {"https://a example", nullptr},
      {"https://a.example https://b.example", nullptr},
      {"https://a_b.example", nullptr},
      {"http://[::1", nullptr},
      {"http://[nonsense]", nullptr},
  };
  for (const Case& c : cases) {
    Result<WebOrigin> parsed = ParseWebOrigin(c.text);
    if (c.origin == nullptr) {
      ASSERT_FALSE(parsed.ok()) << c.text;
      EXPECT_EQ(parsed.status().code(), StatusCode::kInvalidArgument);
    } else {
      ASSERT_TRUE(parsed.ok()) << c.text << ": " << parsed.status().ToString();
      EXPECT_EQ(parsed->ToString(), c.origin) << c.text;
    }
  }
  auto authority = ParseAuthority("https", "Scope.lab.example:8443");
  ASSERT_TRUE(authority.ok());
  EXPECT_EQ(authority->ToString(), "https://scope.lab.example:8443");
  EXPECT_FALSE(ParseAuthority("https", "").ok());
  auto bad = OriginPolicy::Parse({"https://ok.example", "nope"});
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("nope"), std::string::npos);
}

TEST(OriginPolicyTest, AllowsTheListedTheListenersAndTheForwardedOriginsOnly) {
  auto policy = OriginPolicy::Parse({"https://scope.lab.example/octoscope/"});
  ASSERT_TRUE(policy.ok());
  policy->AllowListener(ip::make_address("127.0.0.1"), 8080);
  EXPECT_TRUE(policy->Allows(std::nullopt, std::nullopt));  // No Origin: not a browser.
  for (const char* origin : {"https://scope.lab.example", "https://SCOPE.lab.example:443",
                             "http://127.0.0.1:8080", "http://localhost:8080",
                             "http://[::1]:8080"}) {
    EXPECT_TRUE(policy->Allows(origin, std::nullopt)) << origin;
  }
  for (const char* origin :
       {"http://scope.lab.example", "https://scope.lab.example:8443", "https://evil.example",
        "http://127.0.0.1:8081", "https://127.0.0.1:8080", "http://127.0.0.2:8080", "null", ""}) {
    EXPECT_FALSE(policy->Allows(origin, std::nullopt)) << origin;
  }
  auto forwarded = ParseAuthority("https", "viewer.lab.example");
  ASSERT_TRUE(forwarded.ok());
  EXPECT_TRUE(policy->Allows("https://viewer.lab.example", *forwarded));
  EXPECT_FALSE(policy->Allows("http://viewer.lab.example", *forwarded));
  EXPECT_FALSE(policy->Allows("https://evil.example", *forwarded));

  // A wildcard bind: the loopback names; an IPv6 address in brackets; another loopback address
  // exactly.
  OriginPolicy wildcard;
  wildcard.AllowListener(ip::make_address("0.0.0.0"), 9000);
  EXPECT_TRUE(wildcard.Allows("http://localhost:9000", std::nullopt));
  EXPECT_TRUE(wildcard.Allows("http://127.0.0.1:9000", std::nullopt));
  EXPECT_FALSE(wildcard.Allows("http://0.0.0.0:9000", std::nullopt));
  OriginPolicy v6;
  v6.AllowListener(ip::make_address("fd00::7"), 9000);
  EXPECT_TRUE(v6.Allows("http://[FD00::7]:9000", std::nullopt));
  OriginPolicy other_loopback;
  other_loopback.AllowListener(ip::make_address("127.0.0.2"), 9000);
  EXPECT_TRUE(other_loopback.Allows("http://127.0.0.2:9000", std::nullopt));
  EXPECT_FALSE(other_loopback.Allows("http://localhost:9000", std::nullopt));
}

}  // namespace
}  // namespace octoscope::net
