// Principal and Authenticator: who a request speaks for (docs/api.md, "Authentication"). The net
// layer asks the server's Authenticator about every API request and WebSocket upgrade; the
// Principal it answers travels with the request (HttpRequest::principal,
// WsConnectInfo::principal) so the app decides what that principal may see.
//
// Credentials in a request: "Authorization: Bearer TOKEN" or the query parameter "token" (user
// tokens), "share=TOKEN" (a share link), "view=ID" (a view link). The net layer strips "token",
// "share" and "view" from every query it logs or hands on.
//
// Thread safety: Authenticate and RefusalMessage are called concurrently on I/O threads; they
// must be fast and never block on disk.
#ifndef OCTOSCOPE_NET_PRINCIPAL_H_
#define OCTOSCOPE_NET_PRINCIPAL_H_

#include <optional>
#include <string>
#include <string_view>

namespace octoscope::net {

struct Principal {
  enum class Kind { kUser, kShare, kView };
  Kind kind = Kind::kUser;
  std::string user;        // The user's name ("admin" for the single --token); for a link
                           // followed by a signed-in user, that user's name (display only).
  bool admin = false;      // kUser: sees every dataset, /metrics, may create streams.
  std::string credential;  // kShare: the share token; kView: the view id.
  // kUser: the id the server gave the user's name (stable while the name stays in the users
  // table; a removed name added again gets another one).
  std::string user_id;
};

// Checks a request's credentials; nullopt = 401. Called on I/O threads: fast, never blocks on disk.
class Authenticator {
 public:
  virtual ~Authenticator() = default;
  virtual std::optional<Principal> Authenticate(std::string_view authorization,
                                                std::string_view raw_query) const = 0;

  // The message of the 401 answered when Authenticate refused these credentials ("missing or
  // wrong token", "token expired"); never reveals more than whether a known token expired.
  virtual std::string RefusalMessage(std::string_view authorization,
                                     std::string_view raw_query) const {
    (void)authorization;
    (void)raw_query;
    return "missing or wrong token";
  }
};

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_PRINCIPAL_H_
