// BrickPool: the paper's "brick pool" — every stored brick of the octree, packed
// `bricks_per_page` to a page of a paging::PageCache (and so of its PageStore on disk). A brick
// is identified by a dense uint32 id; id 0 means "no brick". Brick id b lives in page
// (b - 1) / bricks_per_page at byte offset ((b - 1) % bricks_per_page) * brick_bytes.
//
// Allocation is deterministic: Allocate() hands out the LOWEST freed id first and otherwise the
// next never-used id, so the same sequence of Allocate/Free calls always gives the same layout.
// The pool does not initialise brick bytes (a reused id holds its old contents, a fresh one
// whatever its page holds — zeros for a fresh store): the owner writes every byte it relies on.
//
// Invariants: 1 <= id < next_id_ for every id ever handed out; free_ids_ ⊆ [1, next_id_);
// live_bricks() = next_id_ - 1 - |free_ids_|.
//
// Thread safety: all member functions are thread-safe (one internal mutex for the id
// bookkeeping; pinning goes through the thread-safe PageCache). A BrickHandle is a move-only pin
// like paging::PageHandle: one thread at a time; the bytes of one brick may be read by many
// holders but must be modified by one at a time and only after MarkDirty() — coordinating that
// (e.g. striped locks per brick id) is the owner's job.
#ifndef OCTOSCOPE_OCTREE_BRICK_POOL_H_
#define OCTOSCOPE_OCTREE_BRICK_POOL_H_

#include <cstddef>
#include <cstdint>
#include <mutex>
#include <optional>
#include <set>
#include <span>
#include <utility>
#include <vector>

#include "paging/page_cache.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::octree {

// A pin on the page holding one brick, viewing just that brick's bytes.
class BrickHandle {
 public:
  BrickHandle() = default;
  BrickHandle(paging::PageHandle page, uint64_t offset, uint64_t bytes, uint32_t id)
      : page_(std::move(page)), offset_(offset), bytes_(bytes), id_(id) {}

  bool valid() const { return page_.valid(); }
  uint32_t id() const { return id_; }
  // The brick's bytes. REQUIRES: valid(); modify only after MarkDirty().
  std::span<std::byte> data() { return page_.data().subspan(offset_, bytes_); }
  std::span<const std::byte> data() const {
    return std::as_const(page_).data().subspan(offset_, bytes_);
  }
  // Declares a modification (see paging::PageHandle::MarkDirty). REQUIRES: valid().
  void MarkDirty() { page_.MarkDirty(); }
  // Unpins now.
  void Reset() noexcept { page_.Reset(); }

 private:
  paging::PageHandle page_;
  uint64_t offset_ = 0;
  uint64_t bytes_ = 0;
  uint32_t id_ = 0;
};

class BrickPool {
 public:
  // The id bookkeeping, for persistence (Octree::Save/Load).
  struct State {
    uint32_t next_id = 1;            // Ids [1, next_id) were handed out at some time.
    std::vector<uint32_t> free_ids;  // Ascending; each in [1, next_id).
    bool operator==(const State&) const = default;
  };

  // `cache` must outlive the pool. REQUIRES: brick_bytes >= 1, bricks_per_page >= 1,
  // bricks_per_page * brick_bytes <= cache->page_bytes() (Octree checks this and reports
  // kInvalidArgument before constructing a pool).
  BrickPool(paging::PageCache* cache, uint64_t brick_bytes, uint32_t bricks_per_page);

  BrickPool(const BrickPool&) = delete;
  BrickPool& operator=(const BrickPool&) = delete;

  // A new brick id: the lowest freed id, else the next fresh one. kResourceExhausted when all
  // 2^32 - 1 ids are live.
  Result<uint32_t> Allocate();
  // Returns `id` to the pool. Freeing 0, an id never handed out or an id already free is a no-op
  // (a bug of the caller, but never memory corruption).
  void Free(uint32_t id);
  bool IsLive(uint32_t id) const;

  // Pins the page holding brick `id` (loading it on a miss; may block, see PageCache::Pin).
  // kInvalidArgument when `id` is not live.
  Result<BrickHandle> Pin(uint32_t id);
  // Pins only when the page is already in RAM; never does I/O or waits. nullopt when not
  // resident or `id` is not live.
  std::optional<BrickHandle> TryPin(uint32_t id);

  uint64_t brick_bytes() const { return brick_bytes_; }
  uint32_t bricks_per_page() const { return bricks_per_page_; }
  uint64_t live_bricks() const;
  // live_bricks() * brick_bytes().
  uint64_t pool_bytes() const;
  // The page index of brick `id`. REQUIRES: id >= 1.
  uint64_t PageOf(uint32_t id) const { return (id - 1) / bricks_per_page_; }

  State ExportState() const;
  // Replaces the bookkeeping (for a pool created by Load). kCorrupt when the state breaks the
  // invariants (ids out of range, not ascending, duplicates).
  Status ImportState(const State& state);

 private:
  uint64_t OffsetOf(uint32_t id) const { return ((id - 1) % bricks_per_page_) * brick_bytes_; }

  paging::PageCache* const cache_;
  const uint64_t brick_bytes_;
  const uint32_t bricks_per_page_;

  mutable std::mutex mu_;
  uint32_t next_id_ = 1;         // Guarded by mu_.
  std::set<uint32_t> free_ids_;  // Guarded by mu_.
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_BRICK_POOL_H_
