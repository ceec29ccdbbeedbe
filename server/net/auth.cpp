#include "net/auth.h"

#include <cstdint>
#include <utility>

#include "protocol/query_string.h"
#include "util/strings.h"

namespace octoscope::net {

bool ConstantTimeEquals(std::string_view a, std::string_view b) {
  // Every byte of `b` is compared (against a zero past the end of `a`), and the differences are
  // folded without branches, so the loop's time reveals no matching prefix.
  volatile uint8_t diff = a.size() == b.size() ? 0 : 1;
  for (size_t i = 0; i < b.size(); ++i) {
    const uint8_t x = i < a.size() ? static_cast<uint8_t>(a[i]) : 0;
    diff = diff | (x ^ static_cast<uint8_t>(b[i]));
  }
  return diff == 0;
}

RequestCredentials ReadCredentials(std::string_view authorization, std::string_view raw_query) {
  RequestCredentials out;
  const std::string_view auth = TrimWhitespace(authorization);
  constexpr std::string_view kBearer = "bearer ";
  if (auth.size() > kBearer.size() && EqualsIgnoreCase(auth.substr(0, kBearer.size()), kBearer)) {
    out.tokens.emplace_back(TrimWhitespace(auth.substr(kBearer.size())));
  }
  if (raw_query.empty()) return out;
  Result<std::vector<protocol::QueryParameter>> params = protocol::ParseQueryString(raw_query);
  if (!params.ok()) return out;
  for (protocol::QueryParameter& p : *params) {
    if (p.name == "token") {
      out.tokens.push_back(std::move(p.value));
    } else if (p.name == "share" && !out.share) {
      out.share = std::move(p.value);
    } else if (p.name == "view" && !out.view) {
      out.view = std::move(p.value);
    }
  }
  return out;
}

std::string StripCredentials(std::string_view raw_query) {
  std::string q = protocol::RemoveQueryParameter(raw_query, "token");
  q = protocol::RemoveQueryParameter(q, "share");
  return protocol::RemoveQueryParameter(q, "view");
}

bool RequestCarriesToken(std::string_view expected, std::string_view authorization,
                         std::string_view raw_query) {
  // Every candidate is compared in full: no early exit reveals which one matched.
  bool ok = false;
  for (const std::string& t : ReadCredentials(authorization, raw_query).tokens) {
    ok = ConstantTimeEquals(t, expected) || ok;
  }
  return ok;
}

TokenAuthenticator::TokenAuthenticator(std::string token, std::string user)
    : token_(std::move(token)), user_(std::move(user)) {}

std::optional<Principal> TokenAuthenticator::Authenticate(std::string_view authorization,
                                                          std::string_view raw_query) const {
  if (token_.empty() || !RequestCarriesToken(token_, authorization, raw_query)) return std::nullopt;
  Principal p;
  p.kind = Principal::Kind::kUser;
  p.user = user_;
  p.admin = true;
  return p;
}

}  // namespace octoscope::net
