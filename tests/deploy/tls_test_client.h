// TLS clients for the deploy tests: HTTP/1.1 and WebSocket over TLS (Boost.Beast on Asio's
// OpenSSL streams), as a browser talks to nginx in front of `octoscope serve`. The peer's
// certificate is verified against the test's own CA file and the host name "localhost". A client
// may connect from a chosen loopback address (127.0.0.2, ...) so the tests can tell the client's
// address from the proxy's. Every operation has a deadline (tests/net/net_test_client.h).
//
// Thread safety: one client per thread.
#ifndef OCTOSCOPE_TESTS_DEPLOY_TLS_TEST_CLIENT_H_
#define OCTOSCOPE_TESTS_DEPLOY_TLS_TEST_CLIENT_H_

#include <openssl/ssl.h>

#include <boost/asio/ssl.hpp>
#include <boost/beast/ssl.hpp>
#include <boost/beast/websocket/ssl.hpp>
#include <string>
#include <utility>
#include <vector>

#include "net/net_test_client.h"

namespace octoscope::deploy::testing {

using net::testing::HttpResult;
using net::testing::kClientTimeout;
using net::testing::RunOperation;
namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace ssl = asio::ssl;
namespace websocket = beast::websocket;
using tcp = asio::ip::tcp;

constexpr char kTlsHost[] = "localhost";  // The name in the test certificate.

inline ssl::context MakeClientContext(const std::string& ca_file) {
  ssl::context context(ssl::context::tls_client);
  context.set_verify_mode(ssl::verify_peer);
  context.load_verify_file(ca_file);
  return context;
}

// Connects the TCP layer of `stream` from `local_address` to 127.0.0.1:port and performs the TLS
// handshake with host name verification; "" or the error.
template <typename SslStream>
std::string ConnectTls(asio::io_context& ioc, SslStream& stream, uint16_t port,
                       const std::string& local_address) {
  auto& tcp_layer = beast::get_lowest_layer(stream);
  beast::error_code ec;
  tcp_layer.socket().open(tcp::v4(), ec);
  if (!ec) tcp_layer.socket().bind(tcp::endpoint(asio::ip::make_address(local_address), 0), ec);
  if (ec) return "bind " + local_address + ": " + ec.message();
  tcp_layer.expires_after(kClientTimeout);
  const tcp::endpoint endpoint(asio::ip::make_address("127.0.0.1"), port);
  ec = RunOperation(ioc,
                    [&](auto handler) { tcp_layer.async_connect(endpoint, std::move(handler)); });
  if (ec) return "connect: " + ec.message();
  if (!SSL_set_tlsext_host_name(stream.native_handle(), kTlsHost)) return "SNI";
  stream.set_verify_callback(ssl::host_name_verification(kTlsHost));
  tcp_layer.expires_after(kClientTimeout);
  ec = RunOperation(ioc, [&](auto handler) {
    stream.async_handshake(ssl::stream_base::client, std::move(handler));
  });
  return ec ? "TLS handshake: " + ec.message() : "";
}

// One HTTPS connection, kept alive across requests.
class TlsHttpClient {
 public:
  TlsHttpClient(uint16_t port, const std::string& ca_file,
                const std::string& local_address = "127.0.0.1")
      : context_(MakeClientContext(ca_file)), stream_(ioc_, context_) {
    error_ = ConnectTls(ioc_, stream_, port, local_address);
  }

  HttpResult Request(http::verb method, const std::string& target,
                     const std::vector<std::pair<std::string, std::string>>& headers = {},
                     std::string body = {}) {
    HttpResult result;
    if (!error_.empty()) {
      result.error = error_;
      return result;
    }
    http::request<http::string_body> req{method, target, 11};
    req.set(http::field::host, kTlsHost);
    for (const auto& [name, value] : headers) req.set(name, value);
    if (!body.empty() || method == http::verb::post || method == http::verb::put) {
      req.body() = std::move(body);
      req.prepare_payload();
    }
    beast::get_lowest_layer(stream_).expires_after(kClientTimeout);
    beast::error_code ec = RunOperation(
        ioc_, [&](auto handler) { http::async_write(stream_, req, std::move(handler)); });
    if (ec) result.error = "write: " + ec.message();
    http::response_parser<http::string_body> parser;
    parser.body_limit(uint64_t{1} << 30);
    parser.skip(method == http::verb::head);
    beast::get_lowest_layer(stream_).expires_after(kClientTimeout);
    ec = RunOperation(ioc_, [&](auto handler) {
      http::async_read(stream_, buffer_, parser, std::move(handler));
    });
    if (ec) {
      result.error += "read: " + ec.message();
      return result;
    }
    result.status = static_cast<int>(parser.get().result_int());
    result.body = parser.get().body();
    result.headers = parser.get().base();
    result.keep_alive = parser.get().keep_alive();
    return result;
  }

 private:
  asio::io_context ioc_;
  ssl::context context_;
  beast::ssl_stream<beast::tcp_stream> stream_;
  beast::flat_buffer buffer_;
  std::string error_;
};

// A WebSocket client over TLS (wss://).
class TlsWsClient {
 public:
  explicit TlsWsClient(const std::string& ca_file)
      : context_(MakeClientContext(ca_file)), ws_(ioc_, context_) {}

  // Sends `name: value` with the upgrade request (Origin, as a browser does).
  void SetHeader(std::string name, std::string value) {
    ws_.set_option(websocket::stream_base::decorator(
        [name = std::move(name), value = std::move(value)](websocket::request_type& request) {
          request.set(name, value);
        }));
  }

  // TLS, then the upgrade of `target`; "" when open.
  std::string Connect(uint16_t port, const std::string& target,
                      const std::string& local_address = "127.0.0.1") {
    std::string error = ConnectTls(ioc_, ws_.next_layer(), port, local_address);
    if (!error.empty()) return error;
    beast::get_lowest_layer(ws_).expires_after(kClientTimeout);
    beast::error_code ec = RunOperation(ioc_, [&](auto handler) {
      ws_.async_handshake(handshake_response_, kTlsHost, target, std::move(handler));
    });
    beast::get_lowest_layer(ws_).expires_never();
    return ec ? "WebSocket handshake: " + ec.message() : "";
  }
  int handshake_status() const { return static_cast<int>(handshake_response_.result_int()); }

  bool Send(const std::string& text) {
    ws_.text(true);
    bool done = false;
    beast::error_code result;
    ws_.async_write(asio::buffer(text), [&](beast::error_code ec, size_t) {
      result = ec;
      done = true;
    });
    return net::testing::RunOrCancel(ioc_, ws_, done) && !result;
  }

  net::testing::WsMessage Read(std::chrono::steady_clock::duration timeout = kClientTimeout) {
    return net::testing::ReadWsMessage(ioc_, ws_, buffer_, timeout);
  }

  void Close() {
    bool done = false;
    ws_.async_close(websocket::close_code::normal, [&](beast::error_code) { done = true; });
    net::testing::RunOrCancel(ioc_, ws_, done);
  }

 private:
  asio::io_context ioc_;
  ssl::context context_;
  websocket::stream<beast::ssl_stream<beast::tcp_stream>> ws_;
  beast::flat_buffer buffer_;
  websocket::response_type handshake_response_;
};

}  // namespace octoscope::deploy::testing

#endif  // OCTOSCOPE_TESTS_DEPLOY_TLS_TEST_CLIENT_H_
