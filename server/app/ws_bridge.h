// WsBridge: plugs viewing sessions into the net layer's WebSocket endpoint. Each connection is a
// participant of one session::ViewSession: a connection with a user credential creates a new
// session owned under the user's grant — or, with a view link (`/ws?view=ID`), a new session
// owned under the view link's grant, holding the stored view; a connection with a share link
// (`/ws?share=TOKEN`) joins that link's session in the link's role. The owner's `hello` with a
// `resume` key moves the connection back into its earlier session — only one owned under the
// same grant. Text messages go to the session, the connection's end leaves it. The net layer and
// the session layer stay unaware of each other.
//
// Thread safety: the handler's calls come on the connection's strand (net/ws_handler.h); the
// sink adapter may be used from any thread.
#ifndef OCTOSCOPE_APP_WS_BRIDGE_H_
#define OCTOSCOPE_APP_WS_BRIDGE_H_

#include <functional>
#include <memory>
#include <string>
#include <string_view>

#include "net/ws_handler.h"
#include "protocol/grant_ref.h"
#include "session/session_registry.h"
#include "session/view_session.h"

namespace octoscope::app {

// What a connection authenticated as, for the bridge.
struct WsCredential {
  enum class Kind { kUser, kShare, kView };
  Kind kind = Kind::kUser;
  std::string user;        // The user's name ("" for a guest).
  std::string credential;  // kShare: the share token; kView: the view id.
  protocol::GrantRef grant;  // What a session it creates is owned under (kUser, kView).
};

// The credential of a connection (from the net layer's connect info).
using WsCredentialFn = std::function<WsCredential(const net::WsConnectInfo& info)>;

// The factory the net::Server calls per connection. `context` (with its registry, which must be
// set) must outlive the server; what each participant may open is the context's grant checker's.
net::WsHandlerFactory MakeSessionFactory(const session::SessionContext* context,
                                         WsCredentialFn credential,
                                         const session::ViewSessionOptions& options = {});

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_WS_BRIDGE_H_
