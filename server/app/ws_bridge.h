// WsBridge: plugs viewing sessions into the net layer's WebSocket endpoint. Each connection gets
// a session::ViewSession whose SessionSink is the connection's net::WsSink; text messages go to
// the session, the connection's end closes it. The net layer and the session layer stay unaware
// of each other.
//
// Thread safety: the handler's calls come on the connection's strand (net/ws_handler.h); the
// sink adapter may be used from any thread.
#ifndef OCTOSCOPE_APP_WS_BRIDGE_H_
#define OCTOSCOPE_APP_WS_BRIDGE_H_

#include <functional>
#include <memory>
#include <string_view>

#include "net/ws_handler.h"
#include "session/view_session.h"

namespace octoscope::app {

// Whether `principal` may open the dataset `id` (app/access_control.h).
using OpenCheck = std::function<bool(const net::Principal& principal, std::string_view id)>;

// The factory the net::Server calls per connection. `context` must outlive the server. With
// `may_open`, each connection opens only the datasets its principal may see.
net::WsHandlerFactory MakeSessionFactory(const session::SessionContext* context,
                                         const session::ViewSessionOptions& options = {},
                                         OpenCheck may_open = nullptr);

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_WS_BRIDGE_H_
