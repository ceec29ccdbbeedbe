#include "paging/memory_page_store.h"

#include <algorithm>
#include <string>

namespace octoscope::paging {

MemoryPageStore::MemoryPageStore(uint64_t page_bytes) : page_bytes_(page_bytes) {}

uint64_t MemoryPageStore::page_count() const {
  std::lock_guard lock(mu_);
  return page_count_;
}

Status MemoryPageStore::Read(uint64_t page, std::span<std::byte> out) {
  if (out.size() != page_bytes_) {
    return InvalidArgumentError("memory page store: read of page " + std::to_string(page) +
                                " into " + std::to_string(out.size()) + " bytes, page is " +
                                std::to_string(page_bytes_));
  }
  std::lock_guard lock(mu_);
  ++reads_;
  auto it = pages_.find(page);
  if (it == pages_.end() || it->second.bytes.empty()) {
    std::fill(out.begin(), out.end(), std::byte{0});
    if (it != pages_.end())
      ++it->second.reads;
    else
      pages_[page].reads = 1;  // Remember the read count; bytes stay empty (never written).
    return Status::Ok();
  }
  std::copy(it->second.bytes.begin(), it->second.bytes.end(), out.begin());
  ++it->second.reads;
  return Status::Ok();
}

Status MemoryPageStore::Write(uint64_t page, std::span<const std::byte> data) {
  if (data.size() != page_bytes_) {
    return InvalidArgumentError("memory page store: write of page " + std::to_string(page) +
                                " with " + std::to_string(data.size()) + " bytes, page is " +
                                std::to_string(page_bytes_));
  }
  std::lock_guard lock(mu_);
  PageRecord& record = pages_[page];
  record.bytes.assign(data.begin(), data.end());
  ++record.writes;
  ++writes_;
  page_count_ = std::max(page_count_, page + 1);
  return Status::Ok();
}

Status MemoryPageStore::Sync() {
  std::lock_guard lock(mu_);
  ++syncs_;
  return Status::Ok();
}

uint64_t MemoryPageStore::reads() const {
  std::lock_guard lock(mu_);
  return reads_;
}

uint64_t MemoryPageStore::writes() const {
  std::lock_guard lock(mu_);
  return writes_;
}

uint64_t MemoryPageStore::syncs() const {
  std::lock_guard lock(mu_);
  return syncs_;
}

uint64_t MemoryPageStore::read_count(uint64_t page) const {
  std::lock_guard lock(mu_);
  auto it = pages_.find(page);
  return it == pages_.end() ? 0 : it->second.reads;
}

uint64_t MemoryPageStore::write_count(uint64_t page) const {
  std::lock_guard lock(mu_);
  auto it = pages_.find(page);
  return it == pages_.end() ? 0 : it->second.writes;
}

std::optional<std::vector<std::byte>> MemoryPageStore::PageContents(uint64_t page) const {
  std::lock_guard lock(mu_);
  auto it = pages_.find(page);
  if (it == pages_.end() || it->second.bytes.empty()) return std::nullopt;
  return it->second.bytes;
}

}  // namespace octoscope::paging
