// WsHandler and WsSink: what the app plugs into the server's WebSocket endpoint /ws
// (docs/protocol.md). For every accepted connection the server asks the app's WsHandlerFactory
// for a handler, calls OnOpen with the connection's WsSink, passes each text message to OnText
// and reports the end with OnClose. The handler talks back through the sink.
//
// Sending: the sink's queue is the connection's only buffer. Text messages are never dropped;
// binary messages report their fate through a per-message completion (so the session layer can
// count frames in flight). When the bytes queued exceed ServerOptions::max_ws_queue_bytes — a
// client that stopped reading — the connection is closed (TCP, no handshake: a stalled peer
// could not take a close frame anyway), so a stalled client never holds more than that.
//
// Thread safety: OnOpen, OnText and OnClose run one at a time, in order, on the connection's
// strand (an I/O thread) and must not block. OnOpen is always the first call and OnClose, exactly
// once, the last. Every WsSink method may be called from any thread, also after the connection
// closed (sends then complete with sent = false; nothing else happens).
#ifndef OCTOSCOPE_NET_WS_HANDLER_H_
#define OCTOSCOPE_NET_WS_HANDLER_H_

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "net/principal.h"

namespace octoscope::net {

// WebSocket close codes used by the server (RFC 6455, 7.4.1).
inline constexpr uint16_t kCloseNormal = 1000;
inline constexpr uint16_t kCloseGoingAway = 1001;        // Server shutting down.
inline constexpr uint16_t kCloseUnsupportedData = 1003;  // A binary message from the client.
inline constexpr uint16_t kCloseAbnormal = 1006;         // Ended without a close handshake.
inline constexpr uint16_t kClosePolicyViolation = 1008;
inline constexpr uint16_t kCloseTooBig = 1009;
inline constexpr uint16_t kCloseInternalError = 1011;
inline constexpr uint16_t kCloseTryAgainLater = 1013;

class WsSink {
 public:
  // Called once per binary message: true when it was written to the socket, false when it was
  // discarded because the connection closed first. Runs on the connection's strand (or on the
  // caller's thread when the connection is already gone); must not block.
  using SendDone = std::function<void(bool sent)>;

  virtual ~WsSink() = default;

  // Queues a text message (a JSON event). Never dropped while the connection is open.
  virtual void SendText(std::string text) = 0;

  // Queues a binary message (a frame: protocol::FrameHeader + image). The buffer is shared, not
  // copied, and must not change afterwards.
  virtual void SendBinary(std::shared_ptr<const std::vector<uint8_t>> data,
                          SendDone done = nullptr) = 0;

  // Closes with `code` and `reason` (at most 123 bytes, cut otherwise) once the messages queued
  // before have been written; bounded by ServerOptions::ws_close_timeout, after which the
  // connection is dropped. Later sends are discarded.
  virtual void Close(uint16_t code, std::string reason) = 0;

  // Bytes (payloads) and messages queued and not yet written, including the one being written.
  virtual size_t queued_bytes() const = 0;
  virtual size_t queued_messages() const = 0;

  // False once the connection closed or a close was requested.
  virtual bool is_open() const = 0;
};

// Why a connection ended.
struct WsCloseInfo {
  // The close code sent or received; kCloseAbnormal (1006) when the connection ended without a
  // close handshake (reset, timeout, a client that stopped reading).
  uint16_t code = kCloseAbnormal;
  std::string reason;  // One line, for logs.
  bool initiated_by_server = false;
};

class WsHandler {
 public:
  virtual ~WsHandler() = default;
  virtual void OnOpen(std::shared_ptr<WsSink> sink) = 0;
  // One complete text message (at most ServerOptions::max_ws_message_bytes; longer ones close
  // the connection with 1009 before reaching the handler).
  virtual void OnText(std::string text) = 0;
  virtual void OnClose(const WsCloseInfo& info) = 0;
};

struct WsConnectInfo {
  // The peer, "127.0.0.1:54321"; behind a trusted proxy the client's address from
  // X-Forwarded-For ("203.0.113.7", no port).
  std::string remote;
  // "https" when a trusted proxy says so in X-Forwarded-Proto, else "http".
  std::string scheme = "http";
  // The upgrade request's raw query without the "token", "share" and "view" parameters.
  std::string query;
  Principal principal;  // Who the connection speaks for (the Authenticator's answer).
};

// Creates the handler of a new connection (on an I/O thread; must not block). Returning null
// refuses it: the connection is closed with 1013 (try again later).
using WsHandlerFactory = std::function<std::unique_ptr<WsHandler>(const WsConnectInfo& info)>;

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_WS_HANDLER_H_
