#include "net/server_core.h"

namespace octoscope::net::detail {

uint64_t ConnectionRegistry::Add(std::weak_ptr<Connection> connection) {
  std::lock_guard<std::mutex> lock(mu_);
  const uint64_t id = next_id_++;
  connections_.emplace(id, std::move(connection));
  return id;
}

void ConnectionRegistry::Remove(uint64_t id) {
  std::lock_guard<std::mutex> lock(mu_);
  connections_.erase(id);
  if (connections_.empty()) empty_.notify_all();
}

size_t ConnectionRegistry::size() const {
  std::lock_guard<std::mutex> lock(mu_);
  return connections_.size();
}

void ConnectionRegistry::ForEach(const std::function<void(Connection&)>& fn) const {
  std::vector<std::shared_ptr<Connection>> live;
  {
    std::lock_guard<std::mutex> lock(mu_);
    live.reserve(connections_.size());
    for (const auto& [id, weak] : connections_) {
      if (auto c = weak.lock()) live.push_back(std::move(c));
    }
  }
  for (const auto& c : live) fn(*c);
}

bool ConnectionRegistry::WaitEmpty(std::chrono::steady_clock::time_point deadline) const {
  std::unique_lock<std::mutex> lock(mu_);
  return empty_.wait_until(lock, deadline, [&] { return connections_.empty(); });
}

void ServerCore::ClosePosts() {
  std::lock_guard<std::mutex> lock(post_mu_);
  posts_open_ = false;
}

}  // namespace octoscope::net::detail
