#include "net/trusted_proxies.h"

#include <algorithm>
#include <array>
#include <charconv>

#include "util/strings.h"

namespace octoscope::net {
namespace {

namespace ip = boost::asio::ip;

// IPv4-mapped IPv6 addresses (::ffff:a.b.c.d, as a dual-stack socket reports IPv4 peers) compare
// as their IPv4 address.
ip::address Normalize(const ip::address& a) {
  if (a.is_v6() && a.to_v6().is_v4_mapped()) {
    return ip::make_address_v4(ip::v4_mapped, a.to_v6());
  }
  return a;
}

std::array<unsigned char, 16> Bytes(const ip::address& a, size_t* size) {
  std::array<unsigned char, 16> out{};
  if (a.is_v4()) {
    const auto b = a.to_v4().to_bytes();
    std::copy(b.begin(), b.end(), out.begin());
    *size = 4;
  } else {
    out = a.to_v6().to_bytes();
    *size = 16;
  }
  return out;
}

// The first `bits` bits of a and b are equal.
bool SamePrefix(const ip::address& a, const ip::address& b, int bits) {
  if (a.is_v4() != b.is_v4()) return false;
  size_t na = 0, nb = 0;
  const auto x = Bytes(a, &na);
  const auto y = Bytes(b, &nb);
  for (int i = 0; i < bits; ++i) {
    const int byte = i / 8, shift = 7 - i % 8;
    if (((x[byte] >> shift) & 1) != ((y[byte] >> shift) & 1)) return false;
  }
  return true;
}

}  // namespace

std::string AddressText(const ip::address& address) { return Normalize(address).to_string(); }

Result<TrustedProxies> TrustedProxies::Parse(const std::vector<std::string>& entries) {
  TrustedProxies out;
  for (const std::string& entry : entries) {
    const std::string_view text = TrimWhitespace(entry);
    const size_t slash = text.find('/');
    boost::system::error_code ec;
    const ip::address base = Normalize(ip::make_address(std::string(text.substr(0, slash)), ec));
    if (ec) {
      return InvalidArgumentError("trusted-proxy \"" + Printable(entry, 80) +
                                  "\": not an IP address or CIDR network");
    }
    const int max_bits = base.is_v4() ? 32 : 128;
    int bits = max_bits;
    if (slash != std::string_view::npos) {
      const std::string_view b = text.substr(slash + 1);
      const auto [end, err] = std::from_chars(b.data(), b.data() + b.size(), bits);
      if (err != std::errc() || end != b.data() + b.size() || b.empty() || bits < 0 ||
          bits > max_bits) {
        return InvalidArgumentError("trusted-proxy \"" + Printable(entry, 80) +
                                    "\": the prefix length must be 0 to " +
                                    std::to_string(max_bits));
      }
    }
    out.networks_.push_back({base, bits});
  }
  return out;
}

bool TrustedProxies::Contains(const ip::address& address) const {
  const ip::address a = Normalize(address);
  for (const Network& n : networks_) {
    if (SamePrefix(a, n.base, n.bits)) return true;
  }
  return false;
}

std::string TrustedProxies::ClientAddress(const ip::address& peer,
                                          std::string_view forwarded_for) const {
  if (!Contains(peer)) return {};
  // Walk the list from the right: the last hop was added by our proxy, earlier ones by whoever
  // came before it (possibly the client itself).
  std::string client;
  std::string_view rest = forwarded_for;
  while (!rest.empty()) {
    const size_t comma = rest.rfind(',');
    const std::string_view item =
        TrimWhitespace(comma == std::string_view::npos ? rest : rest.substr(comma + 1));
    rest = comma == std::string_view::npos ? std::string_view() : rest.substr(0, comma);
    boost::system::error_code ec;
    const ip::address a = ip::make_address(std::string(item), ec);
    if (ec) break;  // A malformed entry ends what can be believed.
    client = AddressText(a);
    if (!Contains(a)) break;
  }
  return client;
}

}  // namespace octoscope::net
