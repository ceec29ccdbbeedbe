#include "octree/brick_pool.h"

#include <limits>
#include <string>
#include <utility>

namespace octoscope::octree {

BrickPool::BrickPool(paging::PageCache* cache, uint64_t brick_bytes, uint32_t bricks_per_page)
    : cache_(cache), brick_bytes_(brick_bytes), bricks_per_page_(bricks_per_page) {}

Result<uint32_t> BrickPool::Allocate() {
  std::lock_guard<std::mutex> lock(mu_);
  if (!free_ids_.empty()) {
    uint32_t id = *free_ids_.begin();
    free_ids_.erase(free_ids_.begin());
    return id;
  }
  if (next_id_ == std::numeric_limits<uint32_t>::max()) {
    return ResourceExhaustedError("brick pool: all 2^32-1 brick ids are in use");
  }
  return next_id_++;
}

void BrickPool::Free(uint32_t id) {
  std::lock_guard<std::mutex> lock(mu_);
  if (id == 0 || id >= next_id_) return;
  free_ids_.insert(id);
}

bool BrickPool::IsLive(uint32_t id) const {
  std::lock_guard<std::mutex> lock(mu_);
  return id != 0 && id < next_id_ && free_ids_.count(id) == 0;
}

Result<BrickHandle> BrickPool::Pin(uint32_t id) {
  if (!IsLive(id)) {
    return InvalidArgumentError("brick pool: brick " + std::to_string(id) + " is not allocated");
  }
  OCTO_ASSIGN_OR_RETURN(paging::PageHandle page, cache_->Pin(PageOf(id)));
  return BrickHandle(std::move(page), OffsetOf(id), brick_bytes_, id);
}

std::optional<BrickHandle> BrickPool::TryPin(uint32_t id) {
  if (!IsLive(id)) return std::nullopt;
  std::optional<paging::PageHandle> page = cache_->TryPin(PageOf(id));
  if (!page.has_value()) return std::nullopt;
  return BrickHandle(std::move(*page), OffsetOf(id), brick_bytes_, id);
}

uint64_t BrickPool::live_bricks() const {
  std::lock_guard<std::mutex> lock(mu_);
  return uint64_t{next_id_} - 1 - free_ids_.size();
}

uint64_t BrickPool::pool_bytes() const { return live_bricks() * brick_bytes_; }

BrickPool::State BrickPool::ExportState() const {
  std::lock_guard<std::mutex> lock(mu_);
  return State{next_id_, std::vector<uint32_t>(free_ids_.begin(), free_ids_.end())};
}

Status BrickPool::ImportState(const State& state) {
  if (state.next_id == 0) return CorruptError("brick pool state: next id 0");
  std::set<uint32_t> ids;
  uint32_t previous = 0;
  for (uint32_t id : state.free_ids) {
    if (id == 0 || id >= state.next_id || id <= previous) {
      return CorruptError("brick pool state: free id " + std::to_string(id) +
                          " out of order or outside [1, " + std::to_string(state.next_id) + ")");
    }
    previous = id;
    ids.insert(ids.end(), id);
  }
  std::lock_guard<std::mutex> lock(mu_);
  next_id_ = state.next_id;
  free_ids_ = std::move(ids);
  return Status::Ok();
}

}  // namespace octoscope::octree
