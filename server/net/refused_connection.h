// RefusedConnection: a connection accepted over a cap of ConnectionLimits (internal to
// server/net). It is answered at once, before any request is read, with 503 Service Unavailable,
// Retry-After and Connection: close; then the server stops sending, reads and drops what the
// client still sends for a moment (so that the client reads the answer instead of a reset) and
// closes. It holds no place in the limits and lives at most a few seconds, so a flood of refused
// connections costs the server little.
//
// Thread safety: runs on the socket's strand; Start() once, from the acceptor.
#ifndef OCTOSCOPE_NET_REFUSED_CONNECTION_H_
#define OCTOSCOPE_NET_REFUSED_CONNECTION_H_

#include <array>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>
#include <memory>
#include <string>

#include "net/server_core.h"

namespace octoscope::net::detail {

class RefusedConnection : public std::enable_shared_from_this<RefusedConnection> {
 public:
  // `message`: the reason, for the client ({"error": message}).
  RefusedConnection(boost::asio::ip::tcp::socket socket, std::shared_ptr<ServerCore> core,
                    std::string message);

  void Start();

 private:
  void OnWrite(boost::beast::error_code ec);
  void DoDrain();
  void OnDrain(boost::beast::error_code ec, size_t bytes);

  const std::shared_ptr<ServerCore> core_;
  boost::beast::tcp_stream stream_;
  boost::beast::http::response<boost::beast::http::string_body> response_;
  std::array<char, 4096> drain_{};
  size_t drained_ = 0;
};

}  // namespace octoscope::net::detail

#endif  // OCTOSCOPE_NET_REFUSED_CONNECTION_H_
