// HttpSession: one HTTP/1.1 connection (internal to server/net). Reads a request header (at most
// max_header_bytes), checks the route and the credentials, then serves a static file, hands the
// request to the ApiHandler (buffered or streamed body), or turns the connection into a
// WebSocketSession; keep-alive loops back to the next header. One request at a time: the next
// header is read only after the response was written.
//
// Thread safety: every member function runs on the connection's strand; other threads reach the
// session only through ServerCore::Post (HttpResponder, BodyReader, registry calls).
#ifndef OCTOSCOPE_NET_HTTP_SESSION_H_
#define OCTOSCOPE_NET_HTTP_SESSION_H_

#include <array>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/buffer_body.hpp>
#include <boost/beast/http/empty_body.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/http/parser.hpp>
#include <boost/beast/http/string_body.hpp>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "net/api_handler.h"
#include "net/connection_limits.h"
#include "net/server_core.h"

namespace octoscope::net::detail {

// Server, X-Content-Type-Options and Referrer-Policy: on every response of the server.
void ApplyCommonHeaders(boost::beast::http::fields& fields);

class HttpSession : public Connection, public std::enable_shared_from_this<HttpSession> {
 public:
  // `total`: the connection's place among all (ConnectionLimits); `client`: its peer's place, or
  // nothing for a trusted proxy (each request through it takes its client's place).
  HttpSession(boost::asio::ip::tcp::socket socket, std::shared_ptr<ServerCore> core,
              ConnectionLimits::Slot total, ConnectionLimits::Slot client);
  ~HttpSession() override;

  // Registers the connection and starts reading.
  void Start();

  void BeginShutdown() override;
  void ForceClose() override;

  boost::beast::tcp_stream::executor_type executor() { return stream_.get_executor(); }

  // From HttpResponder / BodyReader, on the strand; `request_id` ignores stale calls.
  void DeliverResponse(uint64_t request_id, HttpResponse response);
  void ReadBodyPiece(uint64_t request_id, BodyReader::ReadCallback done);

 private:
  enum class State { kReadingHeader, kReadingBody, kHandling, kWriting, kClosing, kClosed };

  void DoReadHeader();
  void OnReadHeader(boost::beast::error_code ec);
  // Sets remote_, scheme_ and forwarded_client_ of the current request (trusted proxy headers).
  void IdentifyClient();
  // Through a trusted proxy: takes the forwarded client's place (ConnectionLimits); over its cap
  // a 503 was sent and false is returned.
  bool AdmitForwardedClient();
  // Whether the Origin of a WebSocket upgrade may open one (OriginPolicy); logs a refusal.
  bool OriginAllowed();
  void Route();
  // Asks the Authenticator; on success the principal is kept in principal_, else a 401 with the
  // Authenticator's message was sent and false is returned.
  bool Authenticate();
  void ServeStatic();
  void StartApi();
  void OnReadBufferedBody(boost::beast::error_code ec);
  void CallHandler();
  void UpgradeToWebSocket();
  // Writes "100 Continue" first when the client asked for it, then runs `next`.
  void ContinueThen(std::function<void()> next);
  void DoReadPiece();
  void OnReadPiece(boost::beast::error_code ec);
  void FailPiece(Status status);

  // Answers with `status` and a JSON error body; the connection closes afterwards.
  void SendError(int status, std::string_view message, std::vector<HttpHeader> extra = {});
  void SendResponse(HttpResponse response);
  template <typename Message>
  void Write(std::shared_ptr<Message> message, bool close);
  void OnWrite(bool close, int status, uint64_t body_bytes, boost::beast::error_code ec);
  // Half-closes and drains what the client still sends (so it reads our answer instead of a
  // reset), then closes.
  void CloseGracefully();
  void OnLinger(boost::beast::error_code ec, size_t bytes);
  void CloseNow();
  // The request's path for log lines: printable, secret segments redacted, "-" when unknown.
  std::string LoggedPath() const;
  // Whether the response to the current request must close the connection.
  bool MustClose() const;

  const std::shared_ptr<ServerCore> core_;
  boost::beast::tcp_stream stream_;
  boost::beast::flat_buffer buffer_;
  boost::asio::ip::address peer_;  // The socket's peer.
  const bool via_proxy_;           // The peer is a trusted proxy.
  ConnectionLimits::Slot total_slot_;
  // The client's place: the peer's for the connection's life; through a trusted proxy the
  // current request's forwarded client's, given back between requests.
  ConnectionLimits::Slot client_slot_;
  std::string peer_remote_;        // "ADDRESS:PORT" of the peer.
  std::string remote_;             // The request's client: the peer, or whom a trusted proxy names.
  std::string scheme_ = "http";  // Of the current request (X-Forwarded-Proto from a trusted proxy).
  std::string forwarded_client_;  // The address a trusted proxy names for the request, or "".
  uint64_t registry_id_ = 0;
  State state_ = State::kReadingHeader;
  bool shutting_down_ = false;

  // The request being served.
  uint64_t request_id_ = 0;
  std::optional<boost::beast::http::request_parser<boost::beast::http::empty_body>> header_parser_;
  std::optional<boost::beast::http::request_parser<boost::beast::http::string_body>> body_parser_;
  std::optional<boost::beast::http::request_parser<boost::beast::http::buffer_body>> upload_parser_;
  std::string path_;   // Decoded.
  std::string query_;  // Raw.
  Principal principal_;
  std::string method_;
  bool keep_alive_ = false;
  bool body_complete_ = true;                      // The request's body has been read completely.
  bool expect_continue_ = false;                   // "Expect: 100-continue" not answered yet.
  bool continue_writing_ = false;                  // "100 Continue" is being written.
  bool force_close_ = false;                       // The response closes the connection (errors).
  std::optional<HttpResponse> deferred_response_;  // Arrived while "100 Continue" was written.
  std::optional<HttpRequest> pending_;             // Waiting for its buffered body.
  std::chrono::steady_clock::time_point started_;
  // Streamed upload.
  std::vector<uint8_t> piece_;
  BodyReader::ReadCallback piece_done_;
  std::shared_ptr<void> response_;  // The message being written.
  std::shared_ptr<HttpSession> keep_alive_while_handling_;
  std::array<char, 4096> drain_{};
  size_t drained_ = 0;
};

}  // namespace octoscope::net::detail

#endif  // OCTOSCOPE_NET_HTTP_SESSION_H_
