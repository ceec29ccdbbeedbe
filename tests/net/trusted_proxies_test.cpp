#include "net/trusted_proxies.h"

#include <gtest/gtest.h>

namespace octoscope::net {
namespace {

namespace ip = boost::asio::ip;

TEST(TrustedProxiesTest, AddressesAndNetworks) {
  auto p = TrustedProxies::Parse({"127.0.0.1", "10.1.0.0/16", "fd00::/8", " 192.0.2.1/32 "});
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_TRUE(p->Contains(ip::make_address("127.0.0.1")));
  EXPECT_FALSE(p->Contains(ip::make_address("127.0.0.2")));
  EXPECT_TRUE(p->Contains(ip::make_address("10.1.255.3")));
  EXPECT_FALSE(p->Contains(ip::make_address("10.2.0.1")));
  EXPECT_TRUE(p->Contains(ip::make_address("fd12::1")));
  EXPECT_FALSE(p->Contains(ip::make_address("fe80::1")));
  EXPECT_TRUE(p->Contains(ip::make_address("192.0.2.1")));
  // An IPv4 peer seen through a dual-stack socket.
  EXPECT_TRUE(p->Contains(ip::make_address("::ffff:10.1.2.3")));
  auto all = TrustedProxies::Parse({"0.0.0.0/0"});
  ASSERT_TRUE(all.ok());
  EXPECT_TRUE(all->Contains(ip::make_address("203.0.113.7")));
  EXPECT_FALSE(all->Contains(ip::make_address("::1")));
  for (const char* bad : {"", "10.0.0.0/", "10.0.0.0/33", "::/129", "10.0.0.0/-1", "host.example",
                          "10.0.0.0/8x", "1.2.3"}) {
    auto r = TrustedProxies::Parse({bad});
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_NE(r.status().message().find("trusted-proxy"), std::string::npos);
  }
}

TEST(TrustedProxiesTest, ClientIsTheRightmostUntrustedHop) {
  auto p = TrustedProxies::Parse({"127.0.0.1", "10.0.0.0/8"});
  ASSERT_TRUE(p.ok());
  const ip::address proxy = ip::make_address("127.0.0.1");
  EXPECT_EQ(p->ClientAddress(proxy, "203.0.113.7"), "203.0.113.7");
  // A forged first entry is skipped past: the last untrusted hop is the client.
  EXPECT_EQ(p->ClientAddress(proxy, "1.2.3.4, 203.0.113.7"), "203.0.113.7");
  // Inner proxies are walked through.
  EXPECT_EQ(p->ClientAddress(proxy, "203.0.113.7, 10.0.0.5"), "203.0.113.7");
  EXPECT_EQ(p->ClientAddress(proxy, "2001:db8::1"), "2001:db8::1");
  // Garbage ends the walk; nothing believable gives "".
  EXPECT_EQ(p->ClientAddress(proxy, "nonsense"), "");
  EXPECT_EQ(p->ClientAddress(proxy, ""), "");
  EXPECT_EQ(p->ClientAddress(proxy, "nonsense, 203.0.113.7"), "203.0.113.7");
  // An untrusted peer's header is never read.
  EXPECT_EQ(p->ClientAddress(ip::make_address("192.0.2.9"), "203.0.113.7"), "");
}

}  // namespace
}  // namespace octoscope::net
