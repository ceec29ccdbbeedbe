#include "net/refused_connection.h"

#include <boost/asio/dispatch.hpp>
#include <boost/beast/http/write.hpp>
#include <utility>

#include "net/connection_limits.h"
#include "net/http_session.h"

namespace octoscope::net::detail {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;

constexpr std::chrono::seconds kWriteTime{5};
constexpr std::chrono::seconds kDrainTime{1};
constexpr size_t kMaxDrainBytes = size_t{64} << 10;

}  // namespace

RefusedConnection::RefusedConnection(tcp::socket socket, std::shared_ptr<ServerCore> core,
                                     std::string message)
    : core_(std::move(core)), stream_(std::move(socket)) {
  response_.version(11);
  response_.result(http::status::service_unavailable);
  ApplyCommonHeaders(response_);
  response_.set(http::field::cache_control, "no-store");
  response_.set(http::field::content_type, "application/json");
  response_.set(http::field::retry_after, kRetryAfterSeconds);
  response_.body() = HttpResponse::Error(503, message).body;
  response_.keep_alive(false);
  response_.prepare_payload();
}

void RefusedConnection::Start() {
  asio::dispatch(stream_.get_executor(), [self = shared_from_this()] {
    self->stream_.expires_after(kWriteTime);
    http::async_write(self->stream_, self->response_,
                      [self](beast::error_code ec, size_t) { self->OnWrite(ec); });
  });
}

void RefusedConnection::OnWrite(beast::error_code ec) {
  if (!ec) ++core_->responses_by_status[503 - 100];
  beast::error_code shutdown_ec;
  if (!ec) stream_.socket().shutdown(tcp::socket::shutdown_send, shutdown_ec);
  if (ec || shutdown_ec) {
    stream_.close();
    return;
  }
  stream_.expires_after(kDrainTime);
  DoDrain();
}

void RefusedConnection::DoDrain() {
  stream_.async_read_some(asio::buffer(drain_),
                          [self = shared_from_this()](beast::error_code ec, size_t bytes) {
                            self->OnDrain(ec, bytes);
                          });
}

void RefusedConnection::OnDrain(beast::error_code ec, size_t bytes) {
  drained_ += bytes;
  if (ec || drained_ > kMaxDrainBytes) {
    stream_.close();
    return;
  }
  DoDrain();
}

}  // namespace octoscope::net::detail
