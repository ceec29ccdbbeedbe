// Test helpers for the net layer: a capturing logger, a real Beast HTTP client, a raw TCP
// client (for malformed requests) and a real Beast WebSocket client. Every client operation has
// a deadline, so a server bug fails the test instead of hanging it.
#ifndef OCTOSCOPE_TESTS_NET_NET_TEST_CLIENT_H_
#define OCTOSCOPE_TESTS_NET_NET_TEST_CLIENT_H_

#include <unistd.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/read.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core/buffers_to_string.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <utility>
#include <vector>

#include "util/logger.h"

namespace octoscope::net::testing {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;

constexpr std::chrono::seconds kClientTimeout{20};

class CapturingLogger : public Logger {
 public:
  void Log(LogLevel, std::string_view line) override {
    std::lock_guard<std::mutex> lock(mu_);
    lines_.emplace_back(line);
  }
  std::vector<std::string> lines() const {
    std::lock_guard<std::mutex> lock(mu_);
    return lines_;
  }
  bool Contains(std::string_view text) const {
    std::lock_guard<std::mutex> lock(mu_);
    for (const std::string& l : lines_) {
      if (l.find(text) != std::string::npos) return true;
    }
    return false;
  }

 private:
  mutable std::mutex mu_;
  std::vector<std::string> lines_;
};

struct HttpResult {
  int status = 0;  // 0: no response (connection closed or timed out).
  std::string body;
  http::fields headers;
  bool keep_alive = false;
  std::string error;  // Client-side failure, if any.
};

// Runs the io_context until `done` or the deadline; false on timeout.
inline bool RunUntil(asio::io_context& ioc, const bool& done,
                     std::chrono::steady_clock::duration timeout = kClientTimeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  ioc.restart();
  while (!done && std::chrono::steady_clock::now() < deadline) {
    ioc.run_for(std::chrono::milliseconds(10));
    if (ioc.stopped()) ioc.restart();
  }
  return done;
}

// Runs one asynchronous operation to completion. `start` is called with a completion handler;
// tcp_stream's expiry (set by the caller) bounds the time.
template <typename Start>
beast::error_code RunOperation(asio::io_context& ioc, Start start) {
  beast::error_code result;
  bool done = false;
  start([&](beast::error_code ec, auto&&...) {
    result = ec;
    done = true;
  });
  ioc.restart();
  while (!done && ioc.run_one() > 0) {
  }
  return done ? result : beast::error_code(asio::error::timed_out);
}

// One HTTP/1.1 connection to the server, kept alive across requests. `source`, when given, is
// the local address it connects from (any of 127.0.0.0/8 reaches a server on 127.0.0.1).
class HttpClient {
 public:
  explicit HttpClient(uint16_t port, const std::string& source = "") : stream_(ioc_) {
    stream_.expires_after(kClientTimeout);
    const tcp::endpoint endpoint(asio::ip::make_address("127.0.0.1"), port);
    if (!source.empty()) {
      stream_.socket().open(tcp::v4(), connect_error_);
      if (!connect_error_) {
        stream_.socket().bind(tcp::endpoint(asio::ip::make_address(source), 0), connect_error_);
      }
      if (connect_error_) return;
    }
    connect_error_ = RunOperation(
        ioc_, [&](auto handler) { stream_.async_connect(endpoint, std::move(handler)); });
  }

  HttpResult Request(http::verb method, std::string target,
                     std::vector<std::pair<std::string, std::string>> headers = {},
                     std::string body = {}) {
    http::request<http::string_body> req{method, target, 11};
    req.set(http::field::host, "127.0.0.1");
    for (auto& [name, value] : headers) req.set(name, value);
    if (!body.empty() || method == http::verb::post || method == http::verb::put) {
      req.body() = std::move(body);
      req.prepare_payload();
    }
    return Send(req, method == http::verb::head);
  }

  // Writes `req`, then reads one response (also after a failed write: the server may have
  // answered before closing, e.g. 413).
  template <typename Request>
  HttpResult Send(Request& req, bool head = false) {
    HttpResult result;
    if (connect_error_) {
      result.error = "connect: " + connect_error_.message();
      return result;
    }
    stream_.expires_after(kClientTimeout);
    beast::error_code ec = RunOperation(
        ioc_, [&](auto handler) { http::async_write(stream_, req, std::move(handler)); });
    if (ec) result.error = "write: " + ec.message();
    return ReadResponse(std::move(result), head);
  }

  HttpResult ReadResponse(HttpResult result = {}, bool head = false) {
    http::response_parser<http::string_body> parser;
    parser.body_limit(uint64_t{1} << 30);
    parser.skip(head);
    stream_.expires_after(kClientTimeout);
    beast::error_code ec = RunOperation(ioc_, [&](auto handler) {
      http::async_read(stream_, buffer_, parser, std::move(handler));
    });
    if (ec) {
      result.error += (result.error.empty() ? "" : "; ") + std::string("read: ") + ec.message();
      return result;
    }
    auto& res = parser.get();
    result.status = static_cast<int>(res.result_int());
    result.body = res.body();
    result.headers = res.base();
    result.keep_alive = res.keep_alive();
    return result;
  }

  // Writes raw bytes on the connection.
  beast::error_code WriteRaw(std::string_view bytes) {
    stream_.expires_after(kClientTimeout);
    return RunOperation(ioc_, [&](auto handler) {
      asio::async_write(stream_, asio::buffer(bytes.data(), bytes.size()), std::move(handler));
    });
  }

  // True when the server closed the connection (a read sees end of stream or a reset).
  bool ServerClosed(std::chrono::steady_clock::duration timeout = kClientTimeout) {
    char byte;
    stream_.expires_after(timeout);
    beast::error_code ec = RunOperation(ioc_, [&](auto handler) {
      stream_.async_read_some(asio::buffer(&byte, 1), std::move(handler));
    });
    return ec == asio::error::eof || ec == asio::error::connection_reset;
  }

  void Close() { stream_.close(); }

 private:
  asio::io_context ioc_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  beast::error_code connect_error_;
};

inline HttpResult Fetch(uint16_t port, http::verb method, std::string target,
                        std::vector<std::pair<std::string, std::string>> headers = {},
                        std::string body = {}) {
  HttpClient client(port);
  return client.Request(method, std::move(target), std::move(headers), std::move(body));
}

// Sends raw bytes and returns everything the server sends back until it closes the connection
// (or the timeout).
inline std::string RawExchange(uint16_t port, std::string_view request,
                               std::chrono::steady_clock::duration timeout = kClientTimeout) {
  asio::io_context ioc;
  beast::tcp_stream stream(ioc);
  stream.expires_after(timeout);
  const tcp::endpoint endpoint(asio::ip::make_address("127.0.0.1"), port);
  if (RunOperation(ioc,
                   [&](auto handler) { stream.async_connect(endpoint, std::move(handler)); })) {
    return "";
  }
  stream.expires_after(timeout);
  RunOperation(ioc, [&](auto handler) {
    asio::async_write(stream, asio::buffer(request.data(), request.size()), std::move(handler));
  });
  std::string reply;
  char chunk[4096];
  for (;;) {
    size_t n = 0;
    stream.expires_after(timeout);
    beast::error_code ec = RunOperation(ioc, [&](auto handler) {
      stream.async_read_some(asio::buffer(chunk), [&n, handler = std::move(handler)](
                                                      beast::error_code e, size_t bytes) mutable {
        n = bytes;
        handler(e);
      });
    });
    reply.append(chunk, n);
    if (ec) break;
  }
  return reply;
}

// The status code of the first response line in `reply` ("HTTP/1.1 431 ..."), or 0.
inline int StatusOf(std::string_view reply) {
  if (reply.size() < 12 || !reply.starts_with("HTTP/1.1 ")) return 0;
  return std::stoi(std::string(reply.substr(9, 3)));
}

// Runs `ioc` until `done`; past `timeout` cancels `stream`'s socket (and with it the operation)
// and collects the handler. False on timeout.
template <typename Stream>
bool RunOrCancel(asio::io_context& ioc, Stream& stream, const bool& done,
                 std::chrono::steady_clock::duration timeout = kClientTimeout) {
  if (RunUntil(ioc, done, timeout)) return true;
  beast::get_lowest_layer(stream).cancel();
  RunUntil(ioc, done, std::chrono::seconds(5));
  return false;
}

struct WsMessage {
  bool ok = false;  // False: error or timeout (see error).
  bool binary = false;
  std::string data;
  beast::error_code error;
};

// Reads one message of the WebSocket `ws` (any next layer: TCP, TLS) within `timeout`.
template <typename WebSocket>
WsMessage ReadWsMessage(asio::io_context& ioc, WebSocket& ws, beast::flat_buffer& buffer,
                        std::chrono::steady_clock::duration timeout) {
  WsMessage m;
  bool done = false;
  ws.async_read(buffer, [&](beast::error_code ec, size_t) {
    m.error = ec;
    m.ok = !ec;
    done = true;
  });
  if (!RunOrCancel(ioc, ws, done, timeout)) {
    m.ok = false;
    m.error = asio::error::timed_out;
    return m;
  }
  if (m.ok) {
    m.binary = ws.got_binary();
    m.data = beast::buffers_to_string(buffer.data());
    buffer.consume(buffer.size());
  }
  return m;
}

// A WebSocket client; every operation gives up after the timeout.
class WsClient {
 public:
  WsClient() : ws_(ioc_) {}

  // Connects and upgrades; returns the handshake error ("" when open). With a 401 answer the
  // error is Beast's "The WebSocket handshake was declined by the remote peer".
  // `authorization`, when given, is sent as the Authorization header of the upgrade request.
  std::string Connect(uint16_t port, const std::string& target,
                      const std::string& authorization = "") {
    std::vector<std::pair<std::string, std::string>> headers = headers_;
    if (!authorization.empty()) headers.emplace_back("Authorization", authorization);
    if (!headers.empty()) {
      ws_.set_option(websocket::stream_base::decorator([headers](websocket::request_type& request) {
        for (const auto& [name, value] : headers) request.set(name, value);
      }));
    }
    beast::get_lowest_layer(ws_).expires_after(kClientTimeout);
    const tcp::endpoint endpoint(asio::ip::make_address("127.0.0.1"), port);
    beast::error_code ec = RunOperation(ioc_, [&](auto handler) {
      beast::get_lowest_layer(ws_).async_connect(endpoint, std::move(handler));
    });
    if (ec) return "connect: " + ec.message();
    beast::get_lowest_layer(ws_).expires_after(kClientTimeout);
    ec = RunOperation(ioc_, [&](auto handler) {
      ws_.async_handshake(handshake_response_, "127.0.0.1", target, std::move(handler));
    });
    beast::get_lowest_layer(ws_).expires_never();
    return ec ? ec.message() : "";
  }

  // Sends `name: value` with the upgrade request of the next Connect (Origin, X-Forwarded-For, a
  // Host of the test's choice).
  void SetHeader(std::string name, std::string value) {
    headers_.emplace_back(std::move(name), std::move(value));
  }

  int handshake_status() const { return static_cast<int>(handshake_response_.result_int()); }
  // The body of a refused handshake (the server's JSON error).
  const std::string& handshake_body() const { return handshake_response_.body(); }

  // Writes one message; false on error or timeout.
  bool Send(std::string_view text, bool binary = false) {
    ws_.binary(binary);
    bool done = false;
    ws_.async_write(asio::buffer(text.data(), text.size()), [&](beast::error_code ec, size_t) {
      last_error_ = ec;
      done = true;
    });
    if (!RunUntil(ioc_, done)) {
      beast::get_lowest_layer(ws_).cancel();
      RunUntil(ioc_, done, std::chrono::seconds(5));
      return false;
    }
    return !last_error_;
  }

  using Message = WsMessage;

  // Reads one message within `timeout`.
  Message Read(std::chrono::steady_clock::duration timeout = kClientTimeout) {
    return ReadWsMessage(ioc_, ws_, buffer_, timeout);
  }

  // Reads until the server's close frame; returns its code (0 if the connection ended without
  // one or timed out). Data messages read on the way are counted.
  int ReadUntilClose(size_t* messages = nullptr,
                     std::chrono::steady_clock::duration timeout = kClientTimeout) {
    for (;;) {
      Message m = Read(timeout);
      if (m.ok) {
        if (messages) ++*messages;
        continue;
      }
      if (m.error == websocket::error::closed) return ws_.reason().code;
      return 0;
    }
  }

  // Closes with `code` and waits for the server's answer.
  void Close(uint16_t code = 1000) {
    bool done = false;
    ws_.async_close(websocket::close_reason(static_cast<websocket::close_code>(code)),
                    [&](beast::error_code) { done = true; });
    if (!RunUntil(ioc_, done)) {
      beast::get_lowest_layer(ws_).cancel();
      RunUntil(ioc_, done, std::chrono::seconds(5));
    }
  }

  // Stops reading: the socket's receive buffer is made small so the server's writes block soon.
  void ShrinkReceiveBuffer() {
    beast::get_lowest_layer(ws_).socket().set_option(asio::socket_base::receive_buffer_size(4096));
  }

  websocket::stream<beast::tcp_stream>& stream() { return ws_; }
  beast::error_code last_error() const { return last_error_; }

 private:
  asio::io_context ioc_;
  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer buffer_;
  websocket::response_type handshake_response_;
  beast::error_code last_error_;
  std::vector<std::pair<std::string, std::string>> headers_;
};

// Resident set size of this process in bytes (/proc/self/statm).
inline uint64_t ResidentBytes() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long long pages_total = 0, pages_resident = 0;
  const int n = std::fscanf(f, "%llu %llu", &pages_total, &pages_resident);
  std::fclose(f);
  if (n != 2) return 0;
  return pages_resident * static_cast<uint64_t>(sysconf(_SC_PAGESIZE));
}

// Polls `condition` until true or the timeout; returns its last value.
template <typename Condition>
bool WaitFor(Condition condition, std::chrono::steady_clock::duration timeout = kClientTimeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return condition();
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return true;
}

}  // namespace octoscope::net::testing

#endif  // OCTOSCOPE_TESTS_NET_NET_TEST_CLIENT_H_
