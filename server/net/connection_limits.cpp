#include "net/connection_limits.h"

#include <utility>

namespace octoscope::net::detail {

ConnectionLimits::Slot::Slot(Slot&& other) noexcept
    : limits_(std::exchange(other.limits_, nullptr)),
      in_total_(other.in_total_),
      address_(std::move(other.address_)) {}

ConnectionLimits::Slot& ConnectionLimits::Slot::operator=(Slot&& other) noexcept {
  if (this != &other) {
    reset();
    limits_ = std::exchange(other.limits_, nullptr);
    in_total_ = other.in_total_;
    address_ = std::move(other.address_);
  }
  return *this;
}

void ConnectionLimits::Slot::reset() {
  if (limits_ == nullptr) return;
  std::exchange(limits_, nullptr)->Release(in_total_, address_);
  address_.clear();
}

ConnectionLimits::ConnectionLimits(size_t max_total, size_t max_per_address)
    : max_total_(max_total), max_per_address_(max_per_address) {}

std::optional<ConnectionLimits::Slot> ConnectionLimits::AcquireTotal() {
  std::lock_guard<std::mutex> lock(mu_);
  if (total_ >= max_total_) return std::nullopt;
  ++total_;
  return Slot(this, std::nullopt);
}

std::optional<ConnectionLimits::Slot> ConnectionLimits::AcquireAddress(
    const std::string& address) {
  std::lock_guard<std::mutex> lock(mu_);
  size_t& n = per_address_[address];
  if (n >= max_per_address_) return std::nullopt;
  ++n;
  return Slot(this, address);
}

void ConnectionLimits::Release(bool in_total, const std::string& address) {
  std::lock_guard<std::mutex> lock(mu_);
  if (in_total) {
    --total_;
    return;
  }
  auto it = per_address_.find(address);
  if (it != per_address_.end() && --it->second == 0) per_address_.erase(it);
}

size_t ConnectionLimits::total() const {
  std::lock_guard<std::mutex> lock(mu_);
  return total_;
}

size_t ConnectionLimits::count(const std::string& address) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = per_address_.find(address);
  return it == per_address_.end() ? 0 : it->second;
}

uint64_t ConnectionLimits::CountRefusal(std::chrono::steady_clock::time_point now) {
  std::lock_guard<std::mutex> lock(mu_);
  ++unreported_refusals_;
  if (last_report_ && now - *last_report_ < std::chrono::seconds(1)) return 0;
  last_report_ = now;
  return std::exchange(unreported_refusals_, 0);
}

}  // namespace octoscope::net::detail
