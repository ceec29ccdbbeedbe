// ChangeLog: the octree's record of node changes for the consumers that mirror it — the paper's
// "Incremental Octree Updates on the GPU": node creation, deletion and update events that a
// renderer applies to its device node buffer before each pass instead of rebuilding it. Several
// consumers (one per device mirror, plus others) read it, each through its own
// ChangeSubscription (a cursor); the log keeps only what some subscription has not read yet.
//
// Event semantics (see docs/octree_format.md, "Change log"):
//   kCreated  the node id became live (its group of 8 was created; one event per node);
//   kDeleted  the node id stopped being live (its group was freed; it may be reused later);
//   kUpdated  anything else about a live node changed: statistics/averages, child group, brick
//             allocated or dropped, or the BYTES of its brick (interior or apron) — a device copy
//             of that brick is stale and must be re-uploaded.
// Events carry only the id: a consumer applies them in order and reads the CURRENT state of each
// still-live node (Octree::GetNode / ReadBrick), which is always at least as new as the event;
// so replaying an event for state it has already seen is harmless. kCreated/kDeleted are never
// coalesced (an id deleted and recreated between two polls shows both, in order). kUpdated is
// coalesced: the log holds at most one unread kUpdated per id, so one Poll returns at most one
// per id. A further update of that id is dropped while no subscription has read the retained one
// (it stays at the first update, as with a single consumer); once some subscription has read
// it, the retained one is dropped instead (every subscription that has not read it reads the new
// one) and the new one is appended. Reporting an update later than the same id's deletion and
// re-creation changes nothing for a consumer that reads the current state. A dropped update keeps
// its log position until dropped ones are half the log (and >= 1024); then the log is compacted.
//
// Subscribing: Octree::SubscribeChanges() (or ChangeLog::Subscribe) returns a subscription that
// reports the events appended from then on. What happened before is in the tree, not in the
// log: a consumer walks the tree (GetNode from the root) AFTER subscribing, then polls; events
// appended during the walk are still delivered.
//
// Bound: a subscription may fall at most `max_backlog` log positions behind (default
// kDefaultChangeBacklog). When an append would put it further behind, it is marked for
// resynchronisation: it stops pinning the log, and its next Poll returns `resync = true` (and no
// events) and moves it to the current head. The consumer then walks the tree again exactly as
// after subscribing. So the log holds at most max(max_backlog) entries of 8 bytes (over the
// subscriptions not waiting for a resync; the ring allocates at most twice that) plus an index of
// 8 bytes per node id up to the highest id updated (the tree's own node table takes 12 + 16 C
// bytes per id), however long a consumer sleeps; entries no subscription still needs are
// released as soon as the slowest one has read them (or is unsubscribed), and all memory when no
// subscription is up to date. With no subscription Append stores nothing (one atomic load, no
// lock, no allocation); with subscriptions it is amortised O(1).
//
// Thread safety: Append, Subscribe and the statistics may be called from any thread; each
// ChangeSubscription may be used (Poll, destroyed) from any ONE thread at a time, concurrently
// with appends and with other subscriptions. One internal mutex guards the log and all cursors.
// REQUIRES (of the appender): Append(id, ...) is called after the change it reports is visible to
// readers of the tree (the octree appends after releasing the lock of the mutation). Then a
// change that a consumer's walk did not see was ordered after that walk's read, hence after
// Subscribe, and so its Append finds the subscription (the no-subscriber fast path is exact).
#ifndef OCTOSCOPE_OCTREE_CHANGE_LOG_H_
#define OCTOSCOPE_OCTREE_CHANGE_LOG_H_

#include <cstddef>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

namespace octoscope::octree {

enum class NodeChangeKind : uint8_t { kCreated = 0, kUpdated = 1, kDeleted = 2 };

struct NodeChange {
  uint32_t node = 0;  // Node id: 8 * group + octant (root = 0).
  NodeChangeKind kind = NodeChangeKind::kUpdated;
  bool operator==(const NodeChange&) const = default;
};

// How far (in log positions) a subscription may fall behind before it must resynchronise. Beyond
// this many events replaying costs about as much as walking the tree again (one GetNode per event
// versus one per live node; a 4096^3 volume with 64^3 bricks has at most 299,593 nodes, and
// pruning usually removes most), and the ring stays below 4 MiB (at most twice the bound's
// entries of 8 B allocated).
inline constexpr size_t kDefaultChangeBacklog = size_t{1} << 18;

// What one Poll returns.
struct ChangeBatch {
  // true: events this subscription had not read were dropped (it fell more than max_backlog
  // behind); `events` is empty and the subscription now stands at the head. Walk the tree (the
  // consumer's view must be rebuilt from GetNode) and keep polling: what is appended during the
  // walk comes with the next Poll.
  bool resync = false;
  std::vector<NodeChange> events;  // Oldest first: everything appended since the last Poll.
};

class ChangeLog;

// One consumer's cursor into a ChangeLog. Move-only; unsubscribes on destruction (the events only
// it still needed are released at once). A default-constructed or moved-from subscription is
// detached: Poll returns nothing. It may outlive the ChangeLog (then it sees no further events).
class ChangeSubscription {
 public:
  ChangeSubscription() = default;
  ~ChangeSubscription();
  ChangeSubscription(ChangeSubscription&& other) noexcept;
  ChangeSubscription& operator=(ChangeSubscription&& other) noexcept;
  ChangeSubscription(const ChangeSubscription&) = delete;
  ChangeSubscription& operator=(const ChangeSubscription&) = delete;

  // The events since the last Poll (since Subscribe for the first), or the resync verdict.
  ChangeBatch Poll();
  // Log positions appended since the last Poll that this subscription will read (coalesced-away
  // updates still count until compacted); 0 while a resync is pending. For tests and stats.
  uint64_t backlog() const;
  bool attached() const { return cursor_ != nullptr; }

 private:
  friend class ChangeLog;
  struct Core;
  struct Cursor;
  ChangeSubscription(std::shared_ptr<Core> core, Cursor* cursor)
      : core_(std::move(core)), cursor_(cursor) {}
  void Reset();

  std::shared_ptr<Core> core_;
  Cursor* cursor_ = nullptr;  // Owned by core_; read and written under its mutex.
};

class ChangeLog {
 public:
  ChangeLog();
  ~ChangeLog();
  ChangeLog(const ChangeLog&) = delete;
  ChangeLog& operator=(const ChangeLog&) = delete;

  // Records a change for every subscription (nothing at all when there is none). REQUIRES: `node`
  // is an id of the tree's node table (the index is as long as the highest updated id).
  void Append(uint32_t node, NodeChangeKind kind);
  // A new subscription at the head (a max_backlog of 0 counts as 1).
  ChangeSubscription Subscribe(size_t max_backlog = kDefaultChangeBacklog);

  // --- Statistics (tests). ---
  size_t subscribers() const;  // Attached subscriptions (resync pending included).
  size_t retained() const;     // Log entries held (coalesced-away updates included).

 private:
  std::shared_ptr<ChangeSubscription::Core> core_;
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_CHANGE_LOG_H_
