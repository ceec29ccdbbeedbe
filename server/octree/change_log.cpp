#include "octree/change_log.h"

#include <utility>

namespace octoscope::octree {

void ChangeLog::Append(uint32_t node, NodeChangeKind kind) {
  std::lock_guard<std::mutex> lock(mu_);
  if (kind == NodeChangeKind::kUpdated && !updated_.insert(node).second) return;
  events_.push_back(NodeChange{node, kind});
}

std::vector<NodeChange> ChangeLog::Drain() {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<NodeChange> out = std::move(events_);
  events_.clear();
  updated_.clear();
  return out;
}

size_t ChangeLog::pending() const {
  std::lock_guard<std::mutex> lock(mu_);
  return events_.size();
}

}  // namespace octoscope::octree
