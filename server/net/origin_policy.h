// OriginPolicy: which web pages may open WebSockets at /ws (docs/server.md, "Safety"). A browser
// sends the Origin of the page that opens a WebSocket, and sends it with whatever credentials the
// page put into the URL: a page of another site must not drive a viewer on a user's behalf. Allowed
// are the server's own origins — its listening address and its public URL (given as origins) —,
// the configured extra origins, and, for a request through a trusted proxy, the origin the proxy
// serves (X-Forwarded-Proto with X-Forwarded-Host or Host). A request without Origin is not a
// browser's (native clients) and passes; "null", malformed and listed origins do not.
//
// Origins compare by scheme, host (case-insensitively) and port, the scheme's default port
// implied (https://a.example = https://a.example:443); the loopback names localhost, 127.0.0.1
// and [::1] stand for one another.
//
// Thread safety: immutable once built; the const methods are thread-safe.
#ifndef OCTOSCOPE_NET_ORIGIN_POLICY_H_
#define OCTOSCOPE_NET_ORIGIN_POLICY_H_

#include <boost/asio/ip/address.hpp>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"

namespace octoscope::net {

struct WebOrigin {
  std::string scheme;  // "http" or "https".
  std::string host;    // Lower case; an IPv6 address in brackets ("[::1]").
  uint16_t port = 0;   // Given, or the scheme's default.

  // Same scheme and port, and the same host or two loopback names.
  bool Matches(const WebOrigin& other) const;
  // "scheme://host[:port]", the port only when it is not the scheme's default.
  std::string ToString() const;
};

// "http(s)://HOST[:PORT]", or a URL whose origin that is (a path after the host is ignored; a
// query, fragment or user info is not accepted). kInvalidArgument otherwise.
Result<WebOrigin> ParseWebOrigin(std::string_view text);

// The origin of `scheme` ("http"/"https") and `authority` ("HOST[:PORT]" as in a Host header).
Result<WebOrigin> ParseAuthority(std::string_view scheme, std::string_view authority);

class OriginPolicy {
 public:
  // Each entry as for ParseWebOrigin; kInvalidArgument naming the entry otherwise.
  static Result<OriginPolicy> Parse(const std::vector<std::string>& origins);

  // Allows the pages of the server listening on `address`:`port` (any loopback name for a
  // loopback or wildcard address).
  void AllowListener(const boost::asio::ip::address& address, uint16_t port);

  // Whether a WebSocket upgrade with Origin header `origin` (nullopt: none) may proceed;
  // `forwarded`: the origin a trusted proxy says the request was sent to, if any.
  bool Allows(std::optional<std::string_view> origin,
              const std::optional<WebOrigin>& forwarded) const;

  const std::vector<WebOrigin>& origins() const { return origins_; }

 private:
  std::vector<WebOrigin> origins_;
};

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_ORIGIN_POLICY_H_
