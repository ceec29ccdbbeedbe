#include "app/upload_budget.h"

#include <algorithm>
#include <utility>

namespace octoscope::app {

struct UploadBudget::Reservation::State {
  std::mutex mu;
  uint64_t reserved = 0;
};

UploadBudget::Reservation& UploadBudget::Reservation::operator=(Reservation&& other) noexcept {
  if (this != &other) {
    reset();
    state_ = std::move(other.state_);
    bytes_ = std::exchange(other.bytes_, 0);
  }
  return *this;
}

void UploadBudget::Reservation::reset() {
  if (!state_) return;
  {
    std::lock_guard<std::mutex> lock(state_->mu);
    state_->reserved -= bytes_;
  }
  state_.reset();
  bytes_ = 0;
}

UploadBudget::UploadBudget(uint64_t capacity_bytes)
    : capacity_(capacity_bytes), state_(std::make_shared<Reservation::State>()) {}

std::optional<UploadBudget::Reservation> UploadBudget::TryReserve(uint64_t bytes) {
  bytes = std::min(bytes, capacity_);
  std::lock_guard<std::mutex> lock(state_->mu);
  if (bytes > capacity_ - state_->reserved) return std::nullopt;
  state_->reserved += bytes;
  return Reservation(state_, bytes);
}

uint64_t UploadBudget::reserved() const {
  std::lock_guard<std::mutex> lock(state_->mu);
  return state_->reserved;
}

}  // namespace octoscope::app
