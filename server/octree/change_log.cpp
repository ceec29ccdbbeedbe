#include "octree/change_log.h"

#include <algorithm>
#include <atomic>
#include <limits>
#include <mutex>
#include <utility>
#include <vector>

namespace octoscope::octree {

namespace {

// Entry kind of a coalesced-away kUpdated that still occupies its log position.
constexpr uint8_t kDropped = 0xff;
// Compaction runs once dropped entries are this many and at least half the log: each one then
// costs O(log size) and removes at least half of it, so appends stay amortised O(1).
constexpr size_t kMinCompaction = 1024;
constexpr size_t kMinCapacity = 64;
constexpr uint64_t kNever = std::numeric_limits<uint64_t>::max();
constexpr uint64_t kNone = std::numeric_limits<uint64_t>::max();  // No retained kUpdated.

}  // namespace

struct ChangeSubscription::Cursor {
  uint64_t next = 0;         // Log position of the first entry not read yet.
  uint64_t max_backlog = 1;  // Positions it may fall behind before it must resynchronise.
  bool resync = false;       // Fell behind: pins nothing; its next Poll reports the verdict.
};

// The shared state of a log and its subscriptions (kept alive by both). Invariants, under mu:
//  * the ring holds log positions [base, head()) in buf, position base at index `first`;
//  * base == the smallest `next` of the cursors not waiting for a resync (head() when none):
//    what no subscription still needs is trimmed at once;
//  * last_update[id] == p != kNone  <=>  the entry at p is a kUpdated of id (at most one per id;
//    every other update of that id still in the ring is kDropped); ids beyond its size have none;
//  * `dropped` counts kDropped entries;
//  * active, max_next and overflow_at describe the cursors not waiting for a resync: their count,
//    largest `next`, and smallest `next + max_backlog` (Refresh()).
struct ChangeSubscription::Core {
  struct Entry {
    uint32_t node;
    uint8_t kind;  // NodeChangeKind or kDropped.
  };

  std::atomic<size_t> attached{0};  // Subscriptions in any state; Append's lock-free test.
  mutable std::mutex mu;
  std::vector<std::unique_ptr<Cursor>> cursors;
  std::vector<Entry> buf;  // Ring buffer; size 0 or a power of two.
  size_t first = 0;
  size_t size = 0;
  uint64_t base = 0;
  size_t dropped = 0;
  // Indexed by node id (ids are dense: 8 per child group), so it is a fraction of the tree's own
  // node table; a flat array keeps the per-append lookup one cached load, no allocation.
  std::vector<uint64_t> last_update;
  size_t active = 0;
  uint64_t max_next = 0;
  uint64_t overflow_at = kNever;

  uint64_t head() const { return base + size; }
  Entry& At(uint64_t position) {
    return buf[(first + static_cast<size_t>(position - base)) & (buf.size() - 1)];
  }

  void PushBack(Entry entry) {
    if (size == buf.size()) {
      // Grow by doubling, unrolling the ring into the new buffer.
      std::vector<Entry> grown(std::max(kMinCapacity, buf.size() * 2));
      for (size_t i = 0; i < size; ++i) grown[i] = buf[(first + i) & (buf.size() - 1)];
      buf = std::move(grown);
      first = 0;
    }
    buf[(first + size) & (buf.size() - 1)] = entry;
    ++size;
  }

  // Recomputes the cursor summary, then trims every entry below the slowest cursor.
  void Refresh() {
    active = 0;
    max_next = 0;
    overflow_at = kNever;
    uint64_t min_next = head();
    for (const std::unique_ptr<Cursor>& c : cursors) {
      if (c->resync) continue;
      ++active;
      min_next = std::min(min_next, c->next);
      max_next = std::max(max_next, c->next);
      overflow_at = std::min(overflow_at, c->next + c->max_backlog);
    }
    while (base < min_next) {
      const Entry& e = At(base);
      if (e.kind == kDropped) {
        --dropped;
      } else if (e.kind == static_cast<uint8_t>(NodeChangeKind::kUpdated)) {
        last_update[e.node] = kNone;  // The id's one retained update: the index pointed here.
      }
      first = (first + 1) & (buf.size() - 1);
      --size;
      ++base;
    }
    // With no up-to-date subscription nothing is retained: give all memory back. (Otherwise the
    // buffers stay for the next window; they are bounded by max_backlog and the node ids.)
    if (active == 0) {
      std::vector<Entry>().swap(buf);
      std::vector<uint64_t>().swap(last_update);
      first = 0;
    }
  }

  void Append(uint32_t node, NodeChangeKind kind) {
    std::lock_guard<std::mutex> lock(mu);
    if (active == 0) return;  // Only subscriptions waiting for a resync: they need nothing.
    if (kind == NodeChangeKind::kUpdated) {
      if (node >= last_update.size()) last_update.resize(size_t{node} + 1, kNone);
      uint64_t& retained = last_update[node];
      if (retained != kNone) {
        // Unread by every subscription: that entry is read after this change, so it covers it.
        if (retained >= max_next) return;
        // Someone read it already: whoever has not reads the new one instead.
        At(retained).kind = kDropped;
        ++dropped;
      }
      retained = head();
    }
    PushBack(Entry{node, static_cast<uint8_t>(kind)});
    if (head() > overflow_at) {
      // Subscriptions now more than max_backlog behind lose their backlog (resync verdict).
      for (const std::unique_ptr<Cursor>& c : cursors) {
        if (!c->resync && head() - c->next > c->max_backlog) c->resync = true;
      }
      Refresh();
    } else if (dropped >= kMinCompaction && dropped * 2 >= size) {
      Compact();
    }
  }

  // Removes the dropped entries; positions after each one shift down (cursors and the index
  // follow), so the backlog of a slow subscription counts only entries it will read.
  void Compact() {
    std::vector<Cursor*> order;
    for (const std::unique_ptr<Cursor>& c : cursors) {
      if (!c->resync) order.push_back(c.get());
    }
    std::sort(order.begin(), order.end(),
              [](const Cursor* a, const Cursor* b) { return a->next < b->next; });
    size_t k = 0;
    size_t kept = 0;
    for (size_t r = 0; r < size; ++r) {
      for (; k < order.size() && order[k]->next == base + r; ++k) order[k]->next = base + kept;
      const Entry e = At(base + r);
      if (e.kind == kDropped) continue;
      if (e.kind == static_cast<uint8_t>(NodeChangeKind::kUpdated)) {
        last_update[e.node] = base + kept;
      }
      At(base + kept) = e;  // kept <= r: a forward in-place copy.
      ++kept;
    }
    for (; k < order.size(); ++k) order[k]->next = base + kept;
    size = kept;
    dropped = 0;
    Refresh();
  }

  ChangeBatch Poll(Cursor* cursor) {
    ChangeBatch out;
    std::lock_guard<std::mutex> lock(mu);
    if (cursor->resync) {
      out.resync = true;
    } else {
      out.events.reserve(static_cast<size_t>(head() - cursor->next));
      for (uint64_t p = cursor->next; p < head(); ++p) {
        const Entry e = At(p);
        if (e.kind != kDropped) out.events.push_back({e.node, static_cast<NodeChangeKind>(e.kind)});
      }
    }
    cursor->resync = false;
    cursor->next = head();
    Refresh();
    return out;
  }
};

ChangeSubscription::~ChangeSubscription() { Reset(); }

ChangeSubscription::ChangeSubscription(ChangeSubscription&& other) noexcept
    : core_(std::move(other.core_)), cursor_(std::exchange(other.cursor_, nullptr)) {}

ChangeSubscription& ChangeSubscription::operator=(ChangeSubscription&& other) noexcept {
  if (this != &other) {
    Reset();
    core_ = std::move(other.core_);
    cursor_ = std::exchange(other.cursor_, nullptr);
  }
  return *this;
}

void ChangeSubscription::Reset() {
  if (cursor_ == nullptr) return;
  {
    std::lock_guard<std::mutex> lock(core_->mu);
    std::erase_if(core_->cursors,
                  [this](const std::unique_ptr<Cursor>& c) { return c.get() == cursor_; });
    core_->attached.fetch_sub(1, std::memory_order_release);
    core_->Refresh();  // Releases what only this subscription still needed.
  }
  cursor_ = nullptr;
  core_.reset();
}

ChangeBatch ChangeSubscription::Poll() {
  if (cursor_ == nullptr) return {};
  return core_->Poll(cursor_);
}

uint64_t ChangeSubscription::backlog() const {
  if (cursor_ == nullptr) return 0;
  std::lock_guard<std::mutex> lock(core_->mu);
  return cursor_->resync ? 0 : core_->head() - cursor_->next;
}

ChangeLog::ChangeLog() : core_(std::make_shared<ChangeSubscription::Core>()) {}

ChangeLog::~ChangeLog() = default;

void ChangeLog::Append(uint32_t node, NodeChangeKind kind) {
  // No subscription: nothing to record (see the header for why this test is exact).
  if (core_->attached.load(std::memory_order_acquire) == 0) return;
  core_->Append(node, kind);
}

ChangeSubscription ChangeLog::Subscribe(size_t max_backlog) {
  auto cursor = std::make_unique<ChangeSubscription::Cursor>();
  // Capped so that next + max_backlog cannot overflow.
  cursor->max_backlog = std::clamp<uint64_t>(max_backlog, 1, uint64_t{1} << 62);
  ChangeSubscription::Cursor* raw = cursor.get();
  std::lock_guard<std::mutex> lock(core_->mu);
  cursor->next = core_->head();
  core_->cursors.push_back(std::move(cursor));
  core_->attached.fetch_add(1, std::memory_order_release);
  core_->Refresh();
  return ChangeSubscription(core_, raw);
}

size_t ChangeLog::subscribers() const { return core_->attached.load(std::memory_order_acquire); }

size_t ChangeLog::retained() const {
  std::lock_guard<std::mutex> lock(core_->mu);
  return core_->size;
}

}  // namespace octoscope::octree
