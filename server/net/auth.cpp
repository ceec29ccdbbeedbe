#include "net/auth.h"

#include <cstdint>

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

bool RequestCarriesToken(std::string_view expected, std::string_view authorization,
                         std::string_view raw_query) {
  bool ok = false;
  const std::string_view auth = TrimWhitespace(authorization);
  constexpr std::string_view kBearer = "bearer ";
  if (auth.size() > kBearer.size() && EqualsIgnoreCase(auth.substr(0, kBearer.size()), kBearer)) {
    ok = ConstantTimeEquals(TrimWhitespace(auth.substr(kBearer.size())), expected) || ok;
  }
  if (!raw_query.empty()) {
    Result<std::vector<protocol::QueryParameter>> params = protocol::ParseQueryString(raw_query);
    if (params.ok()) {
      for (const protocol::QueryParameter& p : *params) {
        if (p.name == "token") ok = ConstantTimeEquals(p.value, expected) || ok;
      }
    }
  }
  return ok;
}

}  // namespace octoscope::net
