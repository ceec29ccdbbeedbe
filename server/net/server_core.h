// ServerCore: what every connection of a Server shares — options, handlers, logger, the registry
// of open connections (for shutdown) and the guard through which other threads post work to a
// connection's strand. Internal to server/net.
//
// Lifetime: owned jointly by the Server and its connections (shared_ptr); the io_context is not
// part of it. Posts go through Post(), which refuses them once the Server closed the guard, so
// no thread ever posts into a destroyed io_context.
//
// Thread safety: all members are thread-safe.
#ifndef OCTOSCOPE_NET_SERVER_CORE_H_
#define OCTOSCOPE_NET_SERVER_CORE_H_

#include <array>
#include <atomic>
#include <boost/asio/post.hpp>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include "net/api_handler.h"
#include "net/connection_limits.h"
#include "net/origin_policy.h"
#include "net/server.h"
#include "net/trusted_proxies.h"
#include "net/ws_handler.h"
#include "util/logger.h"

namespace octoscope::net::detail {

// A connection as the registry sees it. Both calls may come from any thread; implementations
// post to their strand.
class Connection {
 public:
  virtual ~Connection() = default;
  // Finish what is in flight, then close (HTTP: the current request; WebSocket: close 1001).
  virtual void BeginShutdown() = 0;
  // Close the socket now.
  virtual void ForceClose() = 0;
};

class ConnectionRegistry {
 public:
  // Returns the id to Remove with.
  uint64_t Add(std::weak_ptr<Connection> connection);
  void Remove(uint64_t id);
  size_t size() const;
  // Calls fn on every live connection (outside the registry's lock).
  void ForEach(const std::function<void(Connection&)>& fn) const;
  // Waits until no connection is registered or `deadline` passed; true when empty.
  bool WaitEmpty(std::chrono::steady_clock::time_point deadline) const;

 private:
  mutable std::mutex mu_;
  mutable std::condition_variable empty_;
  uint64_t next_id_ = 1;
  std::unordered_map<uint64_t, std::weak_ptr<Connection>> connections_;
};

struct ServerCore {
  ServerCore(ServerOptions opts, std::shared_ptr<ApiHandler> api_handler, WsHandlerFactory factory,
             Logger& log)
      : options(std::move(opts)),
        api(std::move(api_handler)),
        ws_factory(std::move(factory)),
        logger(log),
        limits(options.max_connections, options.max_connections_per_address) {}

  // Posts fn(session) to the session's strand unless the server stopped or the session is
  // gone; false then. Session must have executor().
  template <typename Session, typename Fn>
  bool Post(const std::weak_ptr<Session>& weak, Fn&& fn) {
    // Declared before the lock: a last reference dropped here is released after unlocking (the
    // session's destructor may post itself).
    std::shared_ptr<Session> session;
    std::lock_guard<std::mutex> lock(post_mu_);
    if (!posts_open_) return false;
    session = weak.lock();
    if (!session) return false;
    try {
      auto executor = session->executor();
      boost::asio::post(executor, [s = session, f = std::forward<Fn>(fn)]() mutable { f(*s); });
    } catch (...) {
      return false;  // Out of memory: treated like a closed connection.
    }
    return true;
  }

  // After this, Post() refuses everything (called before the io_context is destroyed).
  void ClosePosts();

  void Log(LogLevel level, const std::string& line) const { logger.Log(level, line); }

  // Runs a callback into app code; an exception it throws is logged (naming `what`) instead of
  // unwinding into Asio. True when it returned normally.
  template <typename Fn>
  bool CallUser(std::string_view what, Fn&& fn) const {
    try {
      fn();
      return true;
    } catch (const std::exception& e) {
      Log(LogLevel::kError, std::string(what) + " threw: " + e.what());
    } catch (...) {
      Log(LogLevel::kError, std::string(what) + " threw a non-standard exception");
    }
    return false;
  }

  const ServerOptions options;
  const std::shared_ptr<ApiHandler> api;
  const WsHandlerFactory ws_factory;
  Logger& logger;
  std::filesystem::path web_root;  // Canonical, or empty. Set before the first connection.
  TrustedProxies proxies;  // Parsed options.trusted_proxies. Set before the first connection.
  // Parsed options.allowed_origins plus the listening address. Set before the first connection.
  OriginPolicy origins;
  ConnectionLimits limits;
  ConnectionRegistry registry;
  std::atomic<bool> shutting_down{false};
  std::atomic<size_t> websockets{0};
  std::atomic<uint64_t> requests{0};
  // HTTP responses written, by status code (100..599); index = code - 100.
  std::array<std::atomic<uint64_t>, 500> responses_by_status{};

 private:
  std::mutex post_mu_;
  bool posts_open_ = true;
};

}  // namespace octoscope::net::detail

#endif  // OCTOSCOPE_NET_SERVER_CORE_H_
