// LinkAuthenticator: an Authenticator (net/principal.h) that admits, besides the user tokens of
// the one it wraps, the server's share links ("share=TOKEN": a live link of the SessionRegistry,
// unexpired and not revoked) and view links ("view=ID": a view the ViewStore holds). Both are
// answered from memory: no disk access on the I/O threads.
//
// Thread safety: immutable; Authenticate may run concurrently (the registry and the store are
// thread-safe).
#ifndef OCTOSCOPE_APP_LINK_AUTHENTICATOR_H_
#define OCTOSCOPE_APP_LINK_AUTHENTICATOR_H_

#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "net/principal.h"
#include "session/session_registry.h"
#include "session/view_store.h"

namespace octoscope::app {

class LinkAuthenticator : public net::Authenticator {
 public:
  // `registry` and `views` (either may be null: those links are refused) must outlive it.
  LinkAuthenticator(std::shared_ptr<const net::Authenticator> users,
                    const session::SessionRegistry* registry, const session::ViewStore* views);

  std::optional<net::Principal> Authenticate(std::string_view authorization,
                                             std::string_view raw_query) const override;
  std::string RefusalMessage(std::string_view authorization,
                             std::string_view raw_query) const override;

 private:
  std::shared_ptr<const net::Authenticator> users_;
  const session::SessionRegistry* registry_;
  const session::ViewStore* views_;
};

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_LINK_AUTHENTICATOR_H_
