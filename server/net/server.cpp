#include "net/server.h"

#include <boost/asio/dispatch.hpp>
#include <boost/asio/executor_work_guard.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <exception>
#include <mutex>
#include <optional>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include "net/http_session.h"
#include "net/refused_connection.h"
#include "net/server_core.h"

namespace octoscope::net {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
using tcp = asio::ip::tcp;
using detail::ServerCore;

// Accepts connections on its own strand; each connection gets a new strand.
class Listener : public std::enable_shared_from_this<Listener> {
 public:
  Listener(asio::io_context& ioc, std::shared_ptr<ServerCore> core)
      : ioc_(ioc),
        acceptor_(asio::make_strand(ioc)),
        retry_timer_(acceptor_.get_executor()),
        core_(std::move(core)) {}

  Status Open(const tcp::endpoint& endpoint) {
    beast::error_code ec;
    const std::string where =
        endpoint.address().to_string() + ":" + std::to_string(endpoint.port());
    acceptor_.open(endpoint.protocol(), ec);
    if (!ec) acceptor_.set_option(asio::socket_base::reuse_address(true), ec);
    if (!ec) acceptor_.bind(endpoint, ec);
    if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) return UnavailableError("cannot listen on " + where + ": " + ec.message());
    return Status::Ok();
  }

  uint16_t port() const {
    beast::error_code ec;
    const tcp::endpoint e = acceptor_.local_endpoint(ec);
    return ec ? 0 : e.port();
  }

  void Run() {
    asio::dispatch(acceptor_.get_executor(), [self = shared_from_this()] { self->DoAccept(); });
  }

  void Stop() {
    asio::post(acceptor_.get_executor(), [self = shared_from_this()] {
      self->stopped_ = true;
      beast::error_code ignored;
      self->acceptor_.close(ignored);
      self->retry_timer_.cancel();
    });
  }

 private:
  void DoAccept() {
    if (stopped_) return;
    acceptor_.async_accept(asio::make_strand(ioc_),
                           [self = shared_from_this()](beast::error_code ec, tcp::socket socket) {
                             self->OnAccept(ec, std::move(socket));
                           });
  }

  void OnAccept(beast::error_code ec, tcp::socket socket) {
    if (stopped_ || ec == asio::error::operation_aborted) return;
    if (ec) {
      // E.g. out of file descriptors: try again shortly instead of spinning.
      core_->Log(LogLevel::kWarning, "accept failed: " + ec.message());
      retry_timer_.expires_after(std::chrono::milliseconds(100));
      retry_timer_.async_wait([self = shared_from_this()](beast::error_code wait_ec) {
        if (!wait_ec) self->DoAccept();
      });
      return;
    }
    beast::error_code ignored;
    socket.set_option(tcp::no_delay(true), ignored);  // Frames are latency-bound.
    try {
      Admit(std::move(socket));
    } catch (const std::exception& e) {
      core_->Log(LogLevel::kError, std::string("cannot start a connection: ") + e.what());
    }
    DoAccept();
  }

  // Serves the connection, or refuses it when it is over a cap (ConnectionLimits): in all, or
  // of its peer's address unless the peer is a trusted proxy (whose requests are capped by the
  // clients they name, once their headers are read).
  void Admit(tcp::socket socket) {
    using Slot = detail::ConnectionLimits::Slot;
    detail::ConnectionLimits& limits = core_->limits;
    beast::error_code ec;
    const tcp::endpoint peer = socket.remote_endpoint(ec);
    std::optional<Slot> total = limits.AcquireTotal();
    if (!total) {
      return Refuse(std::move(socket), peer, "too many connections to this server",
                    std::to_string(limits.max_total()) + " connections open (max-connections " +
                        std::to_string(limits.max_total()) + ")");
    }
    std::optional<Slot> client;
    if (!ec && !core_->proxies.Contains(peer.address())) {
      const std::string address = AddressText(peer.address());
      client = limits.AcquireAddress(address);
      if (!client) {
        return Refuse(std::move(socket), peer, "too many connections from " + address,
                      std::to_string(limits.max_per_address()) + " connections from " + address +
                          " open (max-connections-per-address " +
                          std::to_string(limits.max_per_address()) + ")");
      }
    }
    std::make_shared<detail::HttpSession>(std::move(socket), core_, std::move(*total),
                                          client ? std::move(*client) : Slot())
        ->Start();
  }

  void Refuse(tcp::socket socket, const tcp::endpoint& peer, const std::string& message,
              const std::string& why) {
    if (const uint64_t refused = core_->limits.CountRefusal(std::chrono::steady_clock::now())) {
      core_->Log(LogLevel::kWarning, "HTTP " + peer.address().to_string() + ":" +
                                         std::to_string(peer.port()) + " refused: " + why +
                                         (refused > 1 ? "; " + std::to_string(refused) +
                                                            " refused since the last report"
                                                      : ""));
    }
    std::make_shared<detail::RefusedConnection>(std::move(socket), core_, message + "; retry later")
        ->Start();
  }

  asio::io_context& ioc_;
  tcp::acceptor acceptor_;
  asio::steady_timer retry_timer_;
  const std::shared_ptr<ServerCore> core_;
  bool stopped_ = false;
};

Status ValidateOptions(const ServerOptions& o) {
  if (!o.authenticator) return InvalidArgumentError("server: an authenticator is required");
  if (o.io_threads < 1 || o.io_threads > 64) {
    return InvalidArgumentError("server: io_threads must be in [1, 64], got " +
                                std::to_string(o.io_threads));
  }
  if (o.max_header_bytes < 1024 || o.max_header_bytes > (size_t{1} << 20)) {
    return InvalidArgumentError("server: max_header_bytes must be in [1 KiB, 1 MiB]");
  }
  if (o.max_json_body_bytes == 0 || o.max_upload_bytes == 0 || o.max_ws_message_bytes == 0 ||
      o.max_ws_queue_bytes == 0) {
    return InvalidArgumentError("server: size limits must be positive");
  }
  if (o.max_connections == 0 || o.max_connections_per_address == 0) {
    return InvalidArgumentError("server: connection caps must be at least 1");
  }
  if (o.upload_chunk_bytes < 4096 || o.upload_chunk_bytes > (size_t{256} << 20)) {
    return InvalidArgumentError("server: upload_chunk_bytes must be in [4 KiB, 256 MiB]");
  }
  for (auto t : {o.read_timeout, o.write_timeout, o.ws_idle_timeout, o.ws_close_timeout,
                 o.shutdown_timeout}) {
    if (t.count() <= 0) return InvalidArgumentError("server: timeouts must be positive");
  }
  return Status::Ok();
}

}  // namespace

struct Server::Impl {
  explicit Impl(int threads) : ioc(threads) {}

  // Declared first: destroyed last, after everything that refers to it.
  asio::io_context ioc;
  std::optional<asio::executor_work_guard<asio::io_context::executor_type>> work;
  std::shared_ptr<ServerCore> core;
  std::shared_ptr<Listener> listener;
  std::vector<std::thread> threads;
  std::mutex shutdown_mu;
  bool stopped = false;
};

Result<std::unique_ptr<Server>> Server::Start(ServerOptions options,
                                              std::shared_ptr<ApiHandler> api,
                                              WsHandlerFactory ws_factory, Logger& logger) {
  OCTO_RETURN_IF_ERROR(ValidateOptions(options));
  if (!api) return InvalidArgumentError("server: no API handler");
  if (!ws_factory) return InvalidArgumentError("server: no WebSocket handler factory");
  beast::error_code ec;
  const asio::ip::address address = asio::ip::make_address(options.bind_address, ec);
  if (ec) {
    return InvalidArgumentError("server: bind address \"" + options.bind_address +
                                "\" is not an IP address");
  }
  std::filesystem::path web_root;
  if (!options.web_root.empty()) {
    std::error_code fs_ec;
    web_root = std::filesystem::canonical(options.web_root, fs_ec);
    if (fs_ec || !std::filesystem::is_directory(web_root, fs_ec)) {
      return NotFoundError("server: web root " + options.web_root.string() + " is not a directory");
    }
  }
  auto proxies = TrustedProxies::Parse(options.trusted_proxies);
  if (!proxies.ok()) return InvalidArgumentError("server: " + proxies.status().message());
  auto origins = OriginPolicy::Parse(options.allowed_origins);
  if (!origins.ok()) {
    return InvalidArgumentError("server: allowed origin " + origins.status().message());
  }
  const tcp::endpoint endpoint(address, options.port);
  const int threads = options.io_threads;

  std::unique_ptr<Server> server(new Server());
  server->impl_ = std::make_unique<Impl>(threads);
  Impl& impl = *server->impl_;
  impl.core = std::make_shared<ServerCore>(std::move(options), std::move(api),
                                           std::move(ws_factory), logger);
  impl.core->web_root = web_root;
  impl.core->proxies = std::move(*proxies);
  impl.listener = std::make_shared<Listener>(impl.ioc, impl.core);
  OCTO_RETURN_IF_ERROR(impl.listener->Open(endpoint));
  server->port_ = impl.listener->port();
  impl.core->origins = std::move(*origins);
  impl.core->origins.AllowListener(address, server->port_);

  impl.work.emplace(asio::make_work_guard(impl.ioc));
  for (int i = 0; i < threads; ++i) {
    try {
      impl.threads.emplace_back([&ioc = impl.ioc, core = impl.core] {
        // A handler that throws must not end the thread (or the process).
        for (;;) {
          try {
            ioc.run();
            return;
          } catch (const std::exception& e) {
            core->Log(LogLevel::kError, std::string("I/O thread: uncaught exception: ") + e.what());
          } catch (...) {
            core->Log(LogLevel::kError, "I/O thread: uncaught non-standard exception");
          }
        }
      });
    } catch (const std::system_error& e) {
      if (impl.threads.empty()) {
        return ResourceExhaustedError(std::string("server: cannot start I/O threads: ") + e.what());
      }
      logger.Log(LogLevel::kWarning,
                 "server: started only " + std::to_string(impl.threads.size()) + " I/O threads");
      break;
    }
  }
  impl.listener->Run();
  logger.Log(LogLevel::kInfo, "listening on " + impl.core->options.bind_address + " port " +
                                  std::to_string(server->port_) + " with " +
                                  std::to_string(impl.threads.size()) + " I/O threads");
  return server;
}

Server::~Server() {
  if (impl_) Shutdown();
}

const std::string& Server::bind_address() const { return impl_->core->options.bind_address; }

void Server::Shutdown() {
  std::lock_guard<std::mutex> lock(impl_->shutdown_mu);
  if (impl_->stopped) return;
  ServerCore& core = *impl_->core;
  if (impl_->ioc.get_executor().running_in_this_thread()) {
    core.Log(LogLevel::kError, "Server::Shutdown called on an I/O thread; ignored");
    return;
  }
  impl_->stopped = true;
  core.shutting_down = true;
  impl_->listener->Stop();
  core.Log(LogLevel::kInfo,
           "shutting down: " + std::to_string(core.registry.size()) + " connections open");
  // Finish what is in flight: responses being prepared, WebSocket queues, close handshakes.
  core.registry.ForEach([](detail::Connection& c) { c.BeginShutdown(); });
  const auto timeout = core.options.shutdown_timeout;
  if (!core.registry.WaitEmpty(std::chrono::steady_clock::now() + timeout)) {
    core.Log(LogLevel::kWarning, std::to_string(core.registry.size()) +
                                     " connections still open after " +
                                     std::to_string(timeout.count()) + " ms; dropping them");
    core.registry.ForEach([](detail::Connection& c) { c.ForceClose(); });
    core.registry.WaitEmpty(std::chrono::steady_clock::now() + std::chrono::seconds(1));
  }
  impl_->work.reset();
  impl_->ioc.stop();
  for (std::thread& t : impl_->threads) t.join();
  impl_->threads.clear();
  // From now on no thread may post into the io_context (it is destroyed with the server).
  core.ClosePosts();
  core.Log(LogLevel::kInfo, "server stopped");
}

size_t Server::open_connections() const { return impl_->core->registry.size(); }

size_t Server::open_websockets() const { return impl_->core->websockets; }

uint64_t Server::requests_served() const { return impl_->core->requests; }

std::vector<std::pair<int, uint64_t>> Server::responses_by_status() const {
  std::vector<std::pair<int, uint64_t>> out;
  const auto& counts = impl_->core->responses_by_status;
  for (size_t i = 0; i < counts.size(); ++i) {
    const uint64_t n = counts[i].load();
    if (n > 0) out.emplace_back(static_cast<int>(i) + 100, n);
  }
  return out;
}

}  // namespace octoscope::net
