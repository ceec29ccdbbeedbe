// MemoryPageStore: a PageStore that keeps its pages in RAM (only pages ever written use memory).
// For tests and as a seam where no disk is wanted; it also counts reads, writes and syncs (in
// total and per page) so tests can check what a cache did to its store.
//
// Thread safety: fully thread-safe (one internal mutex); the counters may be read at any time.
#ifndef OCTOSCOPE_PAGING_MEMORY_PAGE_STORE_H_
#define OCTOSCOPE_PAGING_MEMORY_PAGE_STORE_H_

#include <cstddef>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <span>
#include <vector>

#include "paging/page_store.h"

namespace octoscope::paging {

class MemoryPageStore final : public PageStore {
 public:
  // REQUIRES: page_bytes > 0.
  explicit MemoryPageStore(uint64_t page_bytes);

  uint64_t page_bytes() const override { return page_bytes_; }
  uint64_t page_count() const override;
  Status Read(uint64_t page, std::span<std::byte> out) override;
  Status Write(uint64_t page, std::span<const std::byte> data) override;
  Status Sync() override;

  // Test seams. Counts successful calls only.
  uint64_t reads() const;
  uint64_t writes() const;
  uint64_t syncs() const;
  uint64_t read_count(uint64_t page) const;
  uint64_t write_count(uint64_t page) const;
  // The stored bytes of `page`, or nullopt when it was never written.
  std::optional<std::vector<std::byte>> PageContents(uint64_t page) const;

 private:
  struct PageRecord {
    std::vector<std::byte> bytes;  // Empty until the first write; then exactly page_bytes_.
    uint64_t reads = 0;
    uint64_t writes = 0;
  };

  const uint64_t page_bytes_;
  mutable std::mutex mu_;
  std::map<uint64_t, PageRecord> pages_;         // Guarded by mu_.
  uint64_t page_count_ = 0;                      // Guarded by mu_. Highest written page + 1.
  uint64_t reads_ = 0, writes_ = 0, syncs_ = 0;  // Guarded by mu_.
};

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_PAGING_MEMORY_PAGE_STORE_H_
