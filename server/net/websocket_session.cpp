#include "net/websocket_session.h"

#include <boost/asio/dispatch.hpp>
#include <boost/beast/core/buffers_to_string.hpp>
#include <boost/beast/websocket/error.hpp>
#include <cstdio>
#include <utility>

#include "util/strings.h"

namespace octoscope::net::detail {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;

// Close codes an endpoint may send (RFC 6455 7.4; 1005, 1006 and 1015 are never sent).
bool SendableCloseCode(uint16_t code) {
  return (code >= 1000 && code <= 1003) || (code >= 1007 && code <= 1014) ||
         (code >= 3000 && code <= 4999);
}

// A close reason fits a control frame (123 bytes) and is cut at a UTF-8 boundary.
std::string FitCloseReason(std::string reason) {
  constexpr size_t kMax = 123;
  if (reason.size() <= kMax) return reason;
  size_t end = kMax;
  while (end > 0 && (static_cast<unsigned char>(reason[end]) & 0xC0) == 0x80) --end;
  reason.resize(end);
  return reason;
}

// The handler's view of the connection: every call is posted to the strand.
class SessionSink : public WsSink {
 public:
  SessionSink(std::weak_ptr<WebSocketSession> session, std::shared_ptr<ServerCore> core,
              std::shared_ptr<SinkState> state)
      : session_(std::move(session)), core_(std::move(core)), state_(std::move(state)) {}

  void SendText(std::string text) override {
    if (!state_->open) return;
    Post(std::make_shared<OutgoingMessage>(state_, std::move(text)));
  }

  void SendBinary(std::shared_ptr<const std::vector<uint8_t>> data, SendDone done) override {
    if (!data || !state_->open) {
      if (done) done(false);
      return;
    }
    Post(std::make_shared<OutgoingMessage>(state_, std::move(data), std::move(done)));
  }

  void Close(uint16_t code, std::string reason) override {
    core_->Post(session_, [code, reason = std::move(reason)](WebSocketSession& s) mutable {
      s.RequestClose(code, std::move(reason));
    });
  }

  size_t queued_bytes() const override { return state_->queued_bytes; }
  size_t queued_messages() const override { return state_->queued_messages; }
  bool is_open() const override { return state_->open; }

 private:
  // The message counts as queued from now on; if it cannot be posted it completes (unsent)
  // when the last reference goes.
  void Post(std::shared_ptr<OutgoingMessage> message) {
    core_->Post(session_, [message](WebSocketSession& s) { s.Enqueue(std::move(*message)); });
  }

  const std::weak_ptr<WebSocketSession> session_;
  const std::shared_ptr<ServerCore> core_;
  const std::shared_ptr<SinkState> state_;
};

}  // namespace

OutgoingMessage::OutgoingMessage(std::shared_ptr<SinkState> state, std::string text)
    : state_(std::move(state)), text_(std::move(text)), bytes_(text_.size()) {
  state_->queued_bytes += bytes_;
  ++state_->queued_messages;
}

OutgoingMessage::OutgoingMessage(std::shared_ptr<SinkState> state,
                                 std::shared_ptr<const std::vector<uint8_t>> data,
                                 WsSink::SendDone done)
    : state_(std::move(state)),
      data_(std::move(data)),
      done_(std::move(done)),
      bytes_(data_->size()) {
  state_->queued_bytes += bytes_;
  ++state_->queued_messages;
}

OutgoingMessage::OutgoingMessage(OutgoingMessage&& other) noexcept
    : state_(std::move(other.state_)),
      text_(std::move(other.text_)),
      data_(std::move(other.data_)),
      done_(std::move(other.done_)),
      bytes_(other.bytes_) {
  other.state_ = nullptr;
  other.done_ = nullptr;
}

OutgoingMessage::~OutgoingMessage() { Complete(false); }

asio::const_buffer OutgoingMessage::buffer() const {
  if (data_) return asio::buffer(*data_);
  return asio::buffer(text_);
}

void OutgoingMessage::Complete(bool sent) {
  if (!state_) return;
  state_->queued_bytes -= bytes_;
  --state_->queued_messages;
  state_ = nullptr;
  if (!done_) return;
  auto done = std::move(done_);
  done_ = nullptr;
  try {
    done(sent);
  } catch (...) {
    // A completion must not throw; there is nobody to tell (this may run in a destructor).
  }
}

WebSocketSession::WebSocketSession(tcp::socket socket, std::shared_ptr<ServerCore> core,
                                   WsConnectInfo info, ConnectionLimits::Slot total,
                                   ConnectionLimits::Slot client)
    : core_(std::move(core)),
      ws_(std::move(socket)),
      info_(std::move(info)),
      total_slot_(std::move(total)),
      client_slot_(std::move(client)),
      close_timer_(ws_.get_executor()),
      sink_state_(std::make_shared<SinkState>()) {
  ++core_->websockets;
}

WebSocketSession::~WebSocketSession() {
  sink_state_->open = false;
  if (handler_) {
    // The server stopped before the connection ended on its own.
    auto handler = std::move(handler_);
    core_->CallUser("WsHandler::OnClose", [&] {
      handler->OnClose(WsCloseInfo{kCloseGoingAway, "server stopped", true});
    });
  }
  queue_.clear();  // Completes every queued message unsent.
  --core_->websockets;
  core_->registry.Remove(registry_id_);
}

void WebSocketSession::Start(http::request<http::empty_body> request) {
  registry_id_ = core_->registry.Add(weak_from_this());
  beast::get_lowest_layer(ws_).expires_never();  // The WebSocket keeps its own timeouts.
  websocket::stream_base::timeout timeouts;
  timeouts.handshake_timeout = core_->options.ws_close_timeout;
  timeouts.idle_timeout = core_->options.ws_idle_timeout;
  timeouts.keep_alive_pings = true;
  ws_.set_option(timeouts);
  ws_.set_option(websocket::stream_base::decorator(
      [](websocket::response_type& response) { response.set(http::field::server, "octoscope"); }));
  ws_.read_message_max(core_->options.max_ws_message_bytes);
  ws_.auto_fragment(false);  // One frame per message: frames are large and sent whole.
  ws_.async_accept(request,
                   [self = shared_from_this()](beast::error_code ec) { self->OnAccept(ec); });
}

void WebSocketSession::BeginShutdown() {
  core_->Post(weak_from_this(),
              [](WebSocketSession& s) { s.RequestClose(kCloseGoingAway, "server shutting down"); });
}

void WebSocketSession::ForceClose() {
  core_->Post(weak_from_this(), [](WebSocketSession& s) { s.HardClose("server stopped"); });
}

void WebSocketSession::OnAccept(beast::error_code ec) {
  if (ec) {
    core_->Log(LogLevel::kInfo, "WS " + info_.remote + " handshake failed: " + ec.message());
    finished_ = true;
    sink_state_->open = false;
    beast::get_lowest_layer(ws_).close();
    return;
  }
  accepted_ = true;
  opened_ = std::chrono::steady_clock::now();
  core_->Log(LogLevel::kInfo, "WS " + info_.remote + " open");
  core_->CallUser("WsHandlerFactory", [&] { handler_ = core_->ws_factory(info_); });
  if (!handler_) {
    RequestClose(kCloseTryAgainLater, "no session available");
  } else {
    sink_ = std::make_shared<SessionSink>(weak_from_this(), core_, sink_state_);
    if (!core_->CallUser("WsHandler::OnOpen", [&] { handler_->OnOpen(sink_); })) {
      RequestClose(kCloseInternalError, "internal error");
    }
  }
  if (core_->shutting_down) RequestClose(kCloseGoingAway, "server shutting down");
  DoRead();
}

void WebSocketSession::DoRead() {
  ws_.async_read(read_buffer_,
                 [self = shared_from_this()](beast::error_code ec, size_t) { self->OnRead(ec); });
}

void WebSocketSession::OnRead(beast::error_code ec) {
  if (ec) {
    Finish(ec);
    return;
  }
  ++messages_in_;
  if (close_requested_ || !handler_) {
    read_buffer_.consume(read_buffer_.size());  // Closing: what still arrives is ignored.
  } else if (!ws_.got_text()) {
    read_buffer_.consume(read_buffer_.size());
    RequestClose(kCloseUnsupportedData, "binary messages are not accepted");
  } else {
    std::string text = beast::buffers_to_string(read_buffer_.data());
    read_buffer_.consume(read_buffer_.size());
    if (!core_->CallUser("WsHandler::OnText", [&] { handler_->OnText(std::move(text)); })) {
      RequestClose(kCloseInternalError, "internal error");
    }
  }
  // An idle connection keeps no large read buffer after one big message.
  if (read_buffer_.capacity() > (size_t{16} << 10)) read_buffer_.shrink_to_fit();
  DoRead();
}

void WebSocketSession::Enqueue(OutgoingMessage message) {
  // Completes unsent when the connection is closing or dropped.
  if (finished_ || close_requested_ || !accepted_ || !hard_close_reason_.empty()) return;
  if (!queue_.empty() && sink_state_->queued_bytes > core_->options.max_ws_queue_bytes) {
    core_->Log(LogLevel::kWarning, "WS " + info_.remote + ": " +
                                       std::to_string(sink_state_->queued_bytes.load()) +
                                       " bytes queued, over the limit of " +
                                       std::to_string(core_->options.max_ws_queue_bytes) +
                                       " (client not reading); closing");
    HardClose("send queue over " + std::to_string(core_->options.max_ws_queue_bytes) +
              " bytes (client not reading)");
    return;
  }
  queue_.push_back(std::move(message));
  DoWrite();
}

void WebSocketSession::DoWrite() {
  if (writing_ || finished_) return;
  if (queue_.empty()) {
    if (close_requested_ && !close_sent_) DoClose();
    return;
  }
  writing_ = true;
  const OutgoingMessage& message = queue_.front();
  ws_.text(!message.binary());
  ws_.async_write(message.buffer(),
                  [self = shared_from_this()](beast::error_code ec, size_t) { self->OnWrite(ec); });
}

void WebSocketSession::OnWrite(beast::error_code ec) {
  writing_ = false;
  OutgoingMessage message = std::move(queue_.front());
  queue_.pop_front();
  if (ec) {
    message.Complete(false);
    if (!finished_) HardClose("write failed: " + ec.message());
    return;
  }
  ++messages_out_;
  bytes_out_ += message.bytes();
  message.Complete(true);
  DoWrite();
}

void WebSocketSession::RequestClose(uint16_t code, std::string reason) {
  if (close_requested_ || finished_) return;
  if (!SendableCloseCode(code)) {
    core_->Log(LogLevel::kError, "WS " + info_.remote + ": close code " + std::to_string(code) +
                                     " cannot be sent; using 1011");
    code = kCloseInternalError;
  }
  close_requested_ = true;
  sink_state_->open = false;
  const std::string fitted = FitCloseReason(std::move(reason));
  close_reason_ = websocket::close_reason(static_cast<websocket::close_code>(code),
                                          beast::string_view(fitted.data(), fitted.size()));
  // The queue and the handshake together get ws_close_timeout; then the socket is closed.
  close_timer_.expires_after(core_->options.ws_close_timeout);
  close_timer_.async_wait([self = shared_from_this()](beast::error_code ec) {
    if (!ec) self->HardClose("close timed out");
  });
  DoWrite();
}

void WebSocketSession::DoClose() {
  close_sent_ = true;
  ws_.async_close(close_reason_, [self = shared_from_this()](beast::error_code ec) {
    // The read loop sees the end (error::closed) and finishes; a failed close drops the socket.
    if (ec && !self->finished_) self->HardClose("close failed: " + ec.message());
  });
}

void WebSocketSession::HardClose(const std::string& reason) {
  if (finished_) return;
  if (hard_close_reason_.empty()) hard_close_reason_ = reason;
  sink_state_->open = false;
  beast::error_code ignored;
  beast::get_lowest_layer(ws_).socket().shutdown(tcp::socket::shutdown_both, ignored);
  beast::get_lowest_layer(ws_).close();
}

void WebSocketSession::Finish(beast::error_code ec) {
  if (finished_) return;
  finished_ = true;
  sink_state_->open = false;
  close_timer_.cancel();
  WsCloseInfo info;
  if (!hard_close_reason_.empty()) {
    info = {kCloseAbnormal, hard_close_reason_, true};
  } else if (close_sent_ &&
             (ec == websocket::error::closed || ec == asio::error::operation_aborted)) {
    // Our close handshake ended the read loop (a read suspended behind Beast's close operation
    // completes as aborted once the stream is closed).
    info = {close_reason_.code, std::string(close_reason_.reason.c_str()), true};
  } else if (ec == websocket::error::closed) {
    if (close_requested_) {
      info = {close_reason_.code, std::string(close_reason_.reason.c_str()), true};
    } else {
      const websocket::close_reason& peer = ws_.reason();
      info = {peer.code == websocket::close_code::none ? uint16_t{1005} : uint16_t(peer.code),
              "client closed" +
                  (peer.reason.empty() ? std::string() : ": " + Printable(peer.reason.c_str(), 80)),
              false};
    }
  } else if (ec == websocket::error::message_too_big) {
    info = {kCloseTooBig,
            "message over " + std::to_string(core_->options.max_ws_message_bytes) + " bytes", true};
  } else if (ec == beast::error::timeout) {
    info = {kCloseAbnormal, "timed out", true};
  } else {
    info = {kCloseAbnormal, "connection lost: " + ec.message(), false};
  }
  // Abort a write still in flight (it completes unsent) and discard what waits behind it.
  beast::get_lowest_layer(ws_).close();
  if (writing_) {
    while (queue_.size() > 1) queue_.pop_back();
  } else {
    queue_.clear();
  }
  if (handler_) {
    auto handler = std::move(handler_);
    core_->CallUser("WsHandler::OnClose", [&] { handler->OnClose(info); });
  }
  const double seconds =
      accepted_ ? std::chrono::duration<double>(std::chrono::steady_clock::now() - opened_).count()
                : 0;
  char duration[32];
  std::snprintf(duration, sizeof duration, "%.1f s", seconds);
  core_->Log(LogLevel::kInfo, "WS " + info_.remote + " closed " + std::to_string(info.code) + " " +
                                  info.reason + " (" + std::to_string(messages_in_) + " in, " +
                                  std::to_string(messages_out_) + " out, " +
                                  std::to_string(bytes_out_) + " B, " + duration + ")");
}

}  // namespace octoscope::net::detail
