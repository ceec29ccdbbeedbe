#include "dataset/change_notifier.h"

#include <vector>

namespace octoscope::dataset {

Subscription::Subscription(Subscription&& other) noexcept
    : notifier_(std::move(other.notifier_)), id_(other.id_) {
  other.id_ = 0;
}

Subscription& Subscription::operator=(Subscription&& other) noexcept {
  if (this != &other) {
    Reset();
    notifier_ = std::move(other.notifier_);
    id_ = other.id_;
    other.id_ = 0;
  }
  return *this;
}

Subscription::~Subscription() { Reset(); }

void Subscription::Reset() {
  if (id_ == 0) return;
  if (std::shared_ptr<ChangeNotifier> notifier = notifier_.lock()) notifier->Unsubscribe(id_);
  notifier_.reset();
  id_ = 0;
}

Subscription ChangeNotifier::Subscribe(std::function<void()> callback) {
  auto entry = std::make_shared<Entry>();
  entry->callback = std::move(callback);
  std::lock_guard lock(mu_);
  const uint64_t id = next_id_++;
  entries_.emplace(id, std::move(entry));
  return Subscription(weak_from_this(), id);
}

void ChangeNotifier::Notify() {
  std::vector<std::shared_ptr<Entry>> entries;
  {
    std::lock_guard lock(mu_);
    entries.reserve(entries_.size());
    for (const auto& [id, entry] : entries_) entries.push_back(entry);
  }
  const std::thread::id self = std::this_thread::get_id();
  for (const std::shared_ptr<Entry>& entry : entries) {
    if (entry->caller.load() == self) continue;  // Raised from inside this callback.
    std::lock_guard call(entry->call_mu);
    if (!entry->active) continue;
    entry->caller.store(self);
    try {
      entry->callback();
    } catch (...) {
      // A subscriber's failure must not stop the notifying thread or the other subscribers.
    }
    entry->caller.store(std::thread::id());
  }
}

void ChangeNotifier::Unsubscribe(uint64_t id) {
  std::shared_ptr<Entry> entry;
  {
    std::lock_guard lock(mu_);
    auto it = entries_.find(id);
    if (it == entries_.end()) return;
    entry = std::move(it->second);
    entries_.erase(it);
  }
  if (entry->caller.load() == std::this_thread::get_id()) {
    entry->active = false;  // From inside its own callback: this thread holds call_mu.
    return;
  }
  std::lock_guard call(entry->call_mu);
  entry->active = false;
}

}  // namespace octoscope::dataset
