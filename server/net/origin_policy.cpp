#include "net/origin_policy.h"

#include <charconv>

#include "util/strings.h"

namespace octoscope::net {
namespace {

namespace ip = boost::asio::ip;

uint16_t DefaultPort(std::string_view scheme) { return scheme == "https" ? 443 : 80; }

bool IsLoopbackName(std::string_view host) {
  return host == "localhost" || host == "127.0.0.1" || host == "[::1]";
}

bool IsHostNameChar(char c) {
  return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '-' || c == '.';
}

Status NotAnOrigin(std::string_view text, std::string_view why) {
  // Appended piece by piece: GCC 12 warns (-Wrestrict) about "literal" + std::string here.
  std::string message = "\"";
  message.append(Printable(text, 100)).append("\" is not a web origin (").append(why).append(")");
  return InvalidArgumentError(message);
}

// ParseAuthority with the reason alone as the error's message.
Result<WebOrigin> Authority(std::string_view scheme, std::string_view authority) {
  WebOrigin origin;
  origin.scheme = ToLower(scheme);
  if (origin.scheme != "http" && origin.scheme != "https") {
    return InvalidArgumentError("the scheme must be http or https");
  }
  const std::string text = ToLower(authority);
  std::string_view rest = text;
  if (rest.starts_with('[')) {
    const size_t close = rest.find(']');
    if (close == std::string_view::npos) return InvalidArgumentError("unclosed '['");
    boost::system::error_code ec;
    ip::make_address_v6(std::string(rest.substr(1, close - 1)), ec);
    if (ec) return InvalidArgumentError("not an IPv6 address in brackets");
    origin.host = std::string(rest.substr(0, close + 1));
    rest.remove_prefix(close + 1);
  } else {
    const size_t colon = rest.find(':');
    origin.host = std::string(rest.substr(0, colon));
    rest.remove_prefix(colon == std::string_view::npos ? rest.size() : colon);
    if (origin.host.empty()) return InvalidArgumentError("no host");
    for (char c : origin.host) {
      if (!IsHostNameChar(c)) return InvalidArgumentError("a host name holds A-Z a-z 0-9 - .");
    }
  }
  origin.port = DefaultPort(origin.scheme);
  if (rest.empty()) return origin;
  unsigned port = 0;
  const char* digits = rest.data() + 1;
  const auto [end, error] = std::from_chars(digits, rest.data() + rest.size(), port);
  if (rest[0] != ':' || rest.size() < 2 || rest.size() > 6 || error != std::errc() ||
      end != rest.data() + rest.size() || port < 1 || port > 65535) {
    return InvalidArgumentError("expected HOST[:PORT] with a port of 1 to 65535");
  }
  origin.port = static_cast<uint16_t>(port);
  return origin;
}

}  // namespace

bool WebOrigin::Matches(const WebOrigin& other) const {
  return scheme == other.scheme && port == other.port &&
         (host == other.host || (IsLoopbackName(host) && IsLoopbackName(other.host)));
}

std::string WebOrigin::ToString() const {
  std::string text = scheme + "://" + host;
  if (port != DefaultPort(scheme)) text.append(":").append(std::to_string(port));
  return text;
}

Result<WebOrigin> ParseAuthority(std::string_view scheme, std::string_view authority) {
  Result<WebOrigin> origin = Authority(scheme, authority);
  if (!origin.ok()) return NotAnOrigin(authority, origin.status().message());
  return origin;
}

Result<WebOrigin> ParseWebOrigin(std::string_view text) {
  text = TrimWhitespace(text);
  const size_t separator = text.find("://");
  if (separator == std::string_view::npos) {
    return NotAnOrigin(text, "expected http(s)://HOST[:PORT]");
  }
  if (text.find_first_of("?#@") != std::string_view::npos) {
    return NotAnOrigin(text, "no user, query or fragment");
  }
  std::string_view authority = text.substr(separator + 3);
  authority = authority.substr(0, authority.find('/'));
  Result<WebOrigin> origin = Authority(text.substr(0, separator), authority);
  if (!origin.ok()) return NotAnOrigin(text, origin.status().message());
  return origin;
}

Result<OriginPolicy> OriginPolicy::Parse(const std::vector<std::string>& origins) {
  OriginPolicy policy;
  for (const std::string& entry : origins) {
    OCTO_ASSIGN_OR_RETURN(WebOrigin origin, ParseWebOrigin(entry));
    policy.origins_.push_back(std::move(origin));
  }
  return policy;
}

void OriginPolicy::AllowListener(const ip::address& address, uint16_t port) {
  WebOrigin origin;
  origin.scheme = "http";
  origin.port = port;
  if (address.is_unspecified()) {
    origin.host = "localhost";
  } else if (address.is_v6()) {
    origin.host.append("[").append(address.to_string()).append("]");
  } else {
    origin.host = address.to_string();
  }
  origins_.push_back(std::move(origin));
}

bool OriginPolicy::Allows(std::optional<std::string_view> origin,
                          const std::optional<WebOrigin>& forwarded) const {
  if (!origin) return true;
  const Result<WebOrigin> page = ParseWebOrigin(*origin);
  if (!page.ok()) return false;
  if (forwarded && forwarded->Matches(*page)) return true;
  for (const WebOrigin& allowed : origins_) {
    if (allowed.Matches(*page)) return true;
  }
  return false;
}

}  // namespace octoscope::net
