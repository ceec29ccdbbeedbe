// Server: the HTTP + WebSocket front of `octoscope serve` on Boost.Beast/Asio (docs/server.md,
// "net"). A listener on one address and port, an io_context run by N I/O threads, one strand per
// connection. It serves the web client's static files itself, routes /api and /metrics to the
// app's ApiHandler and WebSocket upgrades at /ws to handlers from the app's WsHandlerFactory,
// after the Authenticator named the request's Principal (net/principal.h). I/O threads never block:
// handlers answer asynchronously, uploads are pulled piece by piece, each WebSocket has its own
// bounded queue.
//
// Limits (ServerOptions; docs/api.md): request line + headers 8 KiB (431, checked before the
// credentials), JSON bodies 64 KiB and uploads 1 GiB (413, enforced while reading), WebSocket
// messages 64 KiB (close 1009), WebSocket send queue 64 MiB (then the connection is dropped); idle
// and stalled connections time out. Malformed HTTP gets 400 and the connection closes; other
// connections never notice. Connections over the caps (in all, per client address) get 503 with
// Retry-After and close; WebSocket upgrades from pages of foreign web origins get 403.
//
// Shutdown(): stop accepting; idle HTTP connections close; HTTP requests in flight finish (their
// responses carry Connection: close); WebSockets are closed with 1001 after their queued
// messages; after shutdown_timeout whatever is left is dropped; then the I/O threads stop.
//
// Thread safety: port(), counters and Shutdown() may be called from any thread except an I/O
// thread (Shutdown waits for them). Every event is logged as one line through the Logger.
#ifndef OCTOSCOPE_NET_SERVER_H_
#define OCTOSCOPE_NET_SERVER_H_

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "net/api_handler.h"
#include "net/principal.h"
#include "net/ws_handler.h"
#include "util/logger.h"
#include "util/result.h"

namespace octoscope::net {

struct ServerOptions {
  std::string bind_address = "127.0.0.1";  // An IPv4 or IPv6 address literal.
  uint16_t port = 0;                       // 0 picks a free port (see Server::port()).
  int io_threads = 2;                      // [1, 64].
  // REQUIRED: decides who each API request and WebSocket upgrade speaks for (net/principal.h).
  std::shared_ptr<const Authenticator> authenticator;
  // Reverse proxies (addresses or CIDR networks, net/trusted_proxies.h) whose X-Forwarded-For and
  // X-Forwarded-Proto headers are believed; from other peers those headers are ignored.
  std::vector<std::string> trusted_proxies;
  // The web client's files; empty serves none (every static path is 404).
  std::filesystem::path web_root;
  // Pages of these web origins ("scheme://host[:port]"; of a URL only its origin counts) may open
  // WebSockets at /ws, besides the server's own listening address and the origin a trusted proxy
  // forwards (net/origin_policy.h); an upgrade with any other Origin header gets 403. Requests
  // without Origin (native clients) are not browsers' and pass.
  std::vector<std::string> allowed_origins;
  // Caps on open connections, HTTP and WebSocket (docs/server.md, "Safety"): in all, checked at
  // accept, and per client address: the peer's, checked at accept, or for requests through a
  // trusted proxy the forwarded client's, checked once the request header is read (the proxy
  // itself counts in all only). Over a cap: 503 with Retry-After, and the connection closes.
  size_t max_connections = 1024;
  size_t max_connections_per_address = 64;
  // Paths whose segment after one of these prefixes is a credential (the view-link ids of
  // /api/views/ID): log lines show "PREFIX<redacted>" instead, whatever the method.
  std::vector<std::string> secret_path_prefixes = {"/api/views/"};

  size_t max_header_bytes = 8 << 10;
  size_t max_json_body_bytes = 64 << 10;
  uint64_t max_upload_bytes = uint64_t{1} << 30;
  size_t upload_chunk_bytes = 1 << 20;  // Largest piece a BodyReader hands out.
  size_t max_ws_message_bytes = 64 << 10;
  size_t max_ws_queue_bytes = 64 << 20;

  // A request header or body piece that does not arrive in this time closes the connection
  // (slow or idle clients, keep-alive connections).
  std::chrono::milliseconds read_timeout{30000};
  // A response that cannot be written in this time closes the connection.
  std::chrono::milliseconds write_timeout{60000};
  // A WebSocket that receives nothing for this long is pinged, then closed.
  std::chrono::milliseconds ws_idle_timeout{60000};
  // How long a WebSocket close (queued messages + handshake) may take before the drop.
  std::chrono::milliseconds ws_close_timeout{5000};
  // How long Shutdown() waits for connections to finish before dropping them.
  std::chrono::milliseconds shutdown_timeout{5000};
};

class Server {
 public:
  // Binds and listens on options.bind_address:options.port and starts the I/O threads.
  // `api` answers /api and /metrics; `ws_factory` creates /ws handlers; `logger` (REQUIRES:
  // outlives the server) gets one line per event. Errors: kInvalidArgument (options),
  // kInvalidArgument also for a malformed trusted proxy, kNotFound (web_root is not a directory),
  // kUnavailable (the address cannot be bound).
  static Result<std::unique_ptr<Server>> Start(ServerOptions options,
                                               std::shared_ptr<ApiHandler> api,
                                               WsHandlerFactory ws_factory, Logger& logger);

  // Shutdown().
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  // The port listened on (the one picked when options.port was 0).
  uint16_t port() const { return port_; }
  const std::string& bind_address() const;

  // Graceful stop, see the header comment; returns when the I/O threads have stopped.
  // Idempotent. REQUIRES: not called on an I/O thread (from a handler).
  void Shutdown();

  // Open connections: HTTP (including those waiting for a handler) and WebSocket.
  size_t open_connections() const;
  size_t open_websockets() const;
  uint64_t requests_served() const;
  // HTTP responses written so far, as (status code, count) for every code seen, ascending (the
  // app's octoscope_http_requests_total{code}).
  std::vector<std::pair<int, uint64_t>> responses_by_status() const;

 private:
  Server() = default;

  struct Impl;
  std::unique_ptr<Impl> impl_;
  uint16_t port_ = 0;
};

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_SERVER_H_
