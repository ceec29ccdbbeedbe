// TrustedProxies: the reverse proxies whose X-Forwarded-For / X-Forwarded-Proto headers the server
// believes (docs/server.md, "Behind a reverse proxy"). From any other peer those headers are
// ignored, so a client cannot forge its address in the logs.
//
// Thread safety: immutable after Parse; all methods are const and thread-safe.
#ifndef OCTOSCOPE_NET_TRUSTED_PROXIES_H_
#define OCTOSCOPE_NET_TRUSTED_PROXIES_H_

#include <boost/asio/ip/address.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"

namespace octoscope::net {

// The address as text, an IPv4-mapped IPv6 address as its IPv4 address ("203.0.113.7"): how
// client addresses are named (logs, ClientAddress, the per-address connection cap).
std::string AddressText(const boost::asio::ip::address& address);

class TrustedProxies {
 public:
  // Each entry an IPv4 or IPv6 address ("127.0.0.1", "::1") or a network in CIDR notation
  // ("10.0.0.0/8", "fd00::/8"). kInvalidArgument naming the entry otherwise.
  static Result<TrustedProxies> Parse(const std::vector<std::string>& entries);

  bool empty() const { return networks_.empty(); }
  // True when `address` (an IPv4-mapped IPv6 address counts as its IPv4 address) lies in one of
  // the networks.
  bool Contains(const boost::asio::ip::address& address) const;

  // The client behind `peer` given the request's X-Forwarded-For value: the right-most address
  // of the header that is not itself a trusted proxy (earlier entries could be forged by the
  // client). Empty when `peer` is not trusted or the header holds no valid address.
  std::string ClientAddress(const boost::asio::ip::address& peer,
                            std::string_view forwarded_for) const;

 private:
  struct Network {
    boost::asio::ip::address base;  // Masked to `bits`.
    int bits = 0;
  };
  std::vector<Network> networks_;
};

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_TRUSTED_PROXIES_H_
