// ChangeLog: the octree's record of node changes since a consumer last drained it — the paper's
// "Incremental Octree Updates on the GPU": node creation, node deletion and node update events
// that a renderer applies to its device node buffer before each pass instead of rebuilding it.
//
// Semantics (see docs/octree_format.md, "Node table"):
//   kCreated  the node id became live (its group of 8 was created; one event per node);
//   kDeleted  the node id stopped being live (its group was freed; it may be reused later);
//   kUpdated  anything else about a live node changed: statistics/averages, child group, brick
//             allocated or dropped, or the BYTES of its brick (interior or apron) — a device copy
//             of that brick is stale and must be re-uploaded.
// Events are returned in the order they first happened. kUpdated is coalesced: a node appears
// at most once as kUpdated per drain (at its first update). kCreated/kDeleted are never
// coalesced, so an id deleted and recreated within one window shows both, in order. Events
// carry only the id: a consumer applies them in order and reads the CURRENT state of each
// still-live node (Octree::GetNode), which is always at least as new as the event.
//
// Thread safety: thread-safe (one internal mutex).
#ifndef OCTOSCOPE_OCTREE_CHANGE_LOG_H_
#define OCTOSCOPE_OCTREE_CHANGE_LOG_H_

#include <cstdint>
#include <mutex>
#include <unordered_set>
#include <vector>

namespace octoscope::octree {

enum class NodeChangeKind : uint8_t { kCreated = 0, kUpdated = 1, kDeleted = 2 };

struct NodeChange {
  uint32_t node = 0;  // Node id: 8 * group + octant (root = 0).
  NodeChangeKind kind = NodeChangeKind::kUpdated;
  bool operator==(const NodeChange&) const = default;
};

class ChangeLog {
 public:
  void Append(uint32_t node, NodeChangeKind kind);
  // Everything appended since the last Drain, oldest first; the log is empty afterwards.
  std::vector<NodeChange> Drain();
  size_t pending() const;

 private:
  mutable std::mutex mu_;
  std::vector<NodeChange> events_;        // Guarded by mu_.
  std::unordered_set<uint32_t> updated_;  // Guarded by mu_: ids with a pending kUpdated.
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_CHANGE_LOG_H_
