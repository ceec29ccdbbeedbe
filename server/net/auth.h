// Auth: the server's one secret check. Every API call and WebSocket upgrade carries the token as
// "Authorization: Bearer TOKEN" or as the query parameter "token" (docs/api.md); the comparison
// takes the same time whatever the position of the first wrong byte.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_NET_AUTH_H_
#define OCTOSCOPE_NET_AUTH_H_

#include <string_view>

namespace octoscope::net {

// True when a == b. The time depends on the lengths only, never on the contents.
bool ConstantTimeEquals(std::string_view a, std::string_view b);

// True when the request carries `expected`: in `authorization` ("Bearer TOKEN", scheme
// case-insensitive) or as a "token" parameter of `raw_query` (percent-encoded, without '?').
// REQUIRES: !expected.empty().
bool RequestCarriesToken(std::string_view expected, std::string_view authorization,
                         std::string_view raw_query);

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_AUTH_H_
