// WebSocketSession: one WebSocket connection at /ws (internal to server/net). Completes the
// handshake of an authorised upgrade request, runs the read loop (text messages to the
// WsHandler, at most max_ws_message_bytes each) and the write loop over a FIFO queue fed by the
// handler's WsSink. The queue is bounded in bytes: a client that stops reading is dropped when
// the queue passes max_ws_queue_bytes, so it never holds more memory than that nor slows anyone.
// Closing: Close() (or the server's shutdown, code 1001) writes what is queued, then performs
// the close handshake, all within ws_close_timeout; otherwise the socket is closed.
//
// Thread safety: every member function runs on the connection's strand; other threads reach the
// session through its WsSink or the registry (ServerCore::Post).
#ifndef OCTOSCOPE_NET_WEBSOCKET_SESSION_H_
#define OCTOSCOPE_NET_WEBSOCKET_SESSION_H_

#include <atomic>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/empty_body.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/beast/websocket/stream.hpp>
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "net/connection_limits.h"
#include "net/server_core.h"
#include "net/ws_handler.h"

namespace octoscope::net::detail {

// Counters a WsSink reads from any thread.
struct SinkState {
  std::atomic<size_t> queued_bytes{0};
  std::atomic<size_t> queued_messages{0};
  std::atomic<bool> open{true};
};

// One queued message. Leaving the queue in any way (written, discarded, destroyed) updates the
// sink's counters and calls the completion exactly once.
class OutgoingMessage {
 public:
  OutgoingMessage(std::shared_ptr<SinkState> state, std::string text);
  OutgoingMessage(std::shared_ptr<SinkState> state,
                  std::shared_ptr<const std::vector<uint8_t>> data, WsSink::SendDone done);
  OutgoingMessage(OutgoingMessage&& other) noexcept;
  OutgoingMessage& operator=(OutgoingMessage&&) = delete;
  ~OutgoingMessage();

  bool binary() const { return data_ != nullptr; }
  size_t bytes() const { return bytes_; }
  boost::asio::const_buffer buffer() const;
  // Releases the counters and reports `sent`. Idempotent.
  void Complete(bool sent);

 private:
  std::shared_ptr<SinkState> state_;  // Null once completed or moved from.
  std::string text_;
  std::shared_ptr<const std::vector<uint8_t>> data_;
  WsSink::SendDone done_;
  size_t bytes_ = 0;
};

class WebSocketSession : public Connection, public std::enable_shared_from_this<WebSocketSession> {
 public:
  // `total`, `client`: the upgraded connection's places in the ConnectionLimits, held until it
  // ends.
  WebSocketSession(boost::asio::ip::tcp::socket socket, std::shared_ptr<ServerCore> core,
                   WsConnectInfo info, ConnectionLimits::Slot total, ConnectionLimits::Slot client);
  ~WebSocketSession() override;

  // Registers the connection and answers the upgrade request. REQUIRES: on the strand.
  void Start(boost::beast::http::request<boost::beast::http::empty_body> request);

  void BeginShutdown() override;
  void ForceClose() override;

  boost::beast::tcp_stream::executor_type executor() { return ws_.get_executor(); }

  // From the sink, on the strand.
  void Enqueue(OutgoingMessage message);
  void RequestClose(uint16_t code, std::string reason);

 private:
  void OnAccept(boost::beast::error_code ec);
  void DoRead();
  void OnRead(boost::beast::error_code ec);
  void DoWrite();
  void OnWrite(boost::beast::error_code ec);
  void DoClose();
  // Drops the TCP connection; the read loop then ends in Finish.
  void HardClose(const std::string& reason);
  // The read loop ended: report to the handler, discard the queue.
  void Finish(boost::beast::error_code ec);

  const std::shared_ptr<ServerCore> core_;
  boost::beast::websocket::stream<boost::beast::tcp_stream> ws_;
  const WsConnectInfo info_;
  ConnectionLimits::Slot total_slot_;
  ConnectionLimits::Slot client_slot_;
  boost::beast::flat_buffer read_buffer_;
  std::deque<OutgoingMessage> queue_;
  boost::asio::steady_timer close_timer_;
  std::shared_ptr<SinkState> sink_state_;
  std::shared_ptr<WsSink> sink_;
  std::unique_ptr<WsHandler> handler_;
  uint64_t registry_id_ = 0;
  bool accepted_ = false;
  bool writing_ = false;
  bool close_requested_ = false;  // By the handler or the server.
  bool close_sent_ = false;
  bool finished_ = false;
  boost::beast::websocket::close_reason close_reason_;
  std::string hard_close_reason_;
  std::chrono::steady_clock::time_point opened_;
  uint64_t messages_in_ = 0;
  uint64_t messages_out_ = 0;
  uint64_t bytes_out_ = 0;
};

}  // namespace octoscope::net::detail

#endif  // OCTOSCOPE_NET_WEBSOCKET_SESSION_H_
