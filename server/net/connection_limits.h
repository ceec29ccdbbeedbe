// ConnectionLimits: the caps on open connections of a Server (docs/server.md, "Safety"): in all,
// and per client address. A connection holds a Slot of the total from its accept to its end, and
// a Slot of its client's address — a direct peer's from the accept, the client a trusted proxy
// names only while that client's request (or the WebSocket it upgraded to) lasts, since one
// proxy connection carries many clients' requests one after another. A connection over a cap is
// refused (503); the others never notice.
//
// Thread safety: all methods are thread-safe; a Slot may be released on any thread. REQUIRES:
// the limits outlive their slots (they live in the ServerCore that every connection holds).
#ifndef OCTOSCOPE_NET_CONNECTION_LIMITS_H_
#define OCTOSCOPE_NET_CONNECTION_LIMITS_H_

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>

namespace octoscope::net::detail {

// What a client refused over a cap is told to wait (Retry-After, seconds).
inline constexpr char kRetryAfterSeconds[] = "5";

class ConnectionLimits {
 public:
  // One connection's place in the total or in its address's count; given back when destroyed
  // or reset. Move-only; default-constructed it holds nothing.
  class Slot {
   public:
    Slot() = default;
    Slot(Slot&& other) noexcept;
    Slot& operator=(Slot&& other) noexcept;
    ~Slot() { reset(); }

    void reset();
    bool held() const { return limits_ != nullptr; }
    const std::string& address() const { return address_; }  // "" for a place in the total.

   private:
    friend class ConnectionLimits;
    Slot(ConnectionLimits* limits, std::optional<std::string> address)
        : limits_(limits), in_total_(!address), address_(std::move(address).value_or("")) {}

    ConnectionLimits* limits_ = nullptr;
    bool in_total_ = false;
    std::string address_;
  };

  // REQUIRES: both at least 1.
  ConnectionLimits(size_t max_total, size_t max_per_address);
  ConnectionLimits(const ConnectionLimits&) = delete;
  ConnectionLimits& operator=(const ConnectionLimits&) = delete;

  // A place among all connections; nullopt when max_total are open.
  std::optional<Slot> AcquireTotal();
  // A place for a connection of `address` (an IP address as text, "203.0.113.7"); nullopt when
  // max_per_address of its connections are open.
  std::optional<Slot> AcquireAddress(const std::string& address);

  size_t total() const;
  size_t count(const std::string& address) const;
  size_t max_total() const { return max_total_; }
  size_t max_per_address() const { return max_per_address_; }

  // Counts one refusal. Returns how many were refused since the last report when a report is
  // due — the first refusal, then at most one a second, so a flood does not flood the log —
  // else 0.
  uint64_t CountRefusal(std::chrono::steady_clock::time_point now);

 private:
  void Release(bool in_total, const std::string& address);

  const size_t max_total_;
  const size_t max_per_address_;
  mutable std::mutex mu_;
  size_t total_ = 0;
  std::unordered_map<std::string, size_t> per_address_;
  uint64_t unreported_refusals_ = 0;
  std::optional<std::chrono::steady_clock::time_point> last_report_;
};

}  // namespace octoscope::net::detail

#endif  // OCTOSCOPE_NET_CONNECTION_LIMITS_H_
