// Auth: reading the credentials of a request and the one-secret Authenticator. Every API call and
// WebSocket upgrade carries a user token as "Authorization: Bearer TOKEN" or as the query
// parameter "token", a share link's token as "share", a view link's id as "view" (docs/api.md);
// secrets are compared in a time that depends on their lengths only.
//
// Thread safety: pure functions; TokenAuthenticator is immutable.
#ifndef OCTOSCOPE_NET_AUTH_H_
#define OCTOSCOPE_NET_AUTH_H_

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "net/principal.h"

namespace octoscope::net {

// True when a == b. The time depends on the lengths only, never on the contents.
bool ConstantTimeEquals(std::string_view a, std::string_view b);

// The credentials of one request. A query that is not valid percent-encoding carries none.
struct RequestCredentials {
  // The bearer token of `authorization` ("Bearer TOKEN", scheme case-insensitive) first, then the
  // value of every "token" query parameter, decoded.
  std::vector<std::string> tokens;
  std::optional<std::string> share;  // The first "share" parameter.
  std::optional<std::string> view;   // The first "view" parameter.
};
RequestCredentials ReadCredentials(std::string_view authorization, std::string_view raw_query);

// `raw_query` without its "token", "share" and "view" parameters: what may be logged or handed on.
std::string StripCredentials(std::string_view raw_query);

// True when the request carries `expected` as a user token (bearer or "token" parameter).
// REQUIRES: !expected.empty().
bool RequestCarriesToken(std::string_view expected, std::string_view authorization,
                         std::string_view raw_query);

// One secret token whose bearer is the admin user `user` (the single --token of `serve`, and
// tests). Share and view credentials are refused.
class TokenAuthenticator : public Authenticator {
 public:
  // REQUIRES: !token.empty().
  explicit TokenAuthenticator(std::string token, std::string user = "admin");
  std::optional<Principal> Authenticate(std::string_view authorization,
                                        std::string_view raw_query) const override;

 private:
  const std::string token_;
  const std::string user_;
};

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_AUTH_H_
