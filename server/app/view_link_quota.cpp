#include "app/view_link_quota.h"

namespace octoscope::app {

Status ViewLinkQuota::Admit(const protocol::GrantRef& owner) {
  if (views_->OwnedBy(owner) >= static_cast<size_t>(max_per_owner_)) {
    return ResourceExhaustedError("too many view links (at most " +
                                  std::to_string(max_per_owner_) +
                                  " per user): delete some first (the share panel lists them)");
  }
  std::lock_guard<std::mutex> lock(mu_);
  auto [it, inserted] =
      rates_.try_emplace(protocol::GrantRefText(owner), per_minute_ / 60.0, per_minute_);
  if (!it->second.Take()) {
    return ResourceExhaustedError("too many view links saved in a minute (at most " +
                                  std::to_string(per_minute_) + "); try again shortly");
  }
  return Status::Ok();
}

}  // namespace octoscope::app
