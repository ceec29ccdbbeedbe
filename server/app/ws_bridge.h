// WsBridge: plugs viewing sessions into the net layer's WebSocket endpoint. Each connection gets
// a session::ViewSession whose SessionSink is the connection's net::WsSink; text messages go to
// the session, the connection's end closes it. The net layer and the session layer stay unaware
// of each other.
//
// Thread safety: the handler's calls come on the connection's strand (net/ws_handler.h); the
// sink adapter may be used from any thread.
#ifndef OCTOSCOPE_APP_WS_BRIDGE_H_
#define OCTOSCOPE_APP_WS_BRIDGE_H_

#include <memory>

#include "net/ws_handler.h"
#include "session/view_session.h"

namespace octoscope::app {

// The factory the net::Server calls per connection. `context` must outlive the server.
net::WsHandlerFactory MakeSessionFactory(const session::SessionContext* context,
                                         const session::ViewSessionOptions& options = {});

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_WS_BRIDGE_H_
