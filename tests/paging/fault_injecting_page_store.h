// FaultInjectingPageStore: a test PageStore that forwards to another store and fails chosen
// operations: the Nth read or write from now, every read/write of one page (or of the pages a
// predicate picks), every write, Sync; a
// failing write can be made "torn" (it stores a prefix of the new page before failing, as a real
// disk may). Hooks run before each read/write (outside this store's lock) so tests can block an
// operation to observe what other threads do meanwhile. Reusable by the octree tests:
//   #include "paging/fault_injecting_page_store.h"
//
// Thread safety: fully thread-safe; configuration may change while other threads do I/O.
#ifndef OCTOSCOPE_TESTS_PAGING_FAULT_INJECTING_PAGE_STORE_H_
#define OCTOSCOPE_TESTS_PAGING_FAULT_INJECTING_PAGE_STORE_H_

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "paging/page_store.h"
#include "util/status.h"

namespace octoscope::paging {

class FaultInjectingPageStore final : public PageStore {
 public:
  // `inner` must outlive this store.
  explicit FaultInjectingPageStore(PageStore* inner) : inner_(inner) {}

  uint64_t page_bytes() const override { return inner_->page_bytes(); }
  uint64_t page_count() const override { return inner_->page_count(); }

  // --- Configuration -------------------------------------------------------------------------
  // Fail the n-th Read / Write call counted from now (1 = the next one); 0 disables.
  void FailNthRead(uint64_t n) {
    std::lock_guard lock(mu_);
    fail_read_countdown_ = n;
  }
  void FailNthWrite(uint64_t n) {
    std::lock_guard lock(mu_);
    fail_write_countdown_ = n;
  }
  // Fail every write whose call number (1-based, over the store's life) is a multiple of n; 0 off.
  void FailEveryNthWrite(uint64_t n) {
    std::lock_guard lock(mu_);
    fail_every_nth_write_ = n;
  }
  // Fail every read / write of `page` (nullopt: none).
  void FailReadsOfPage(std::optional<uint64_t> page) {
    std::lock_guard lock(mu_);
    fail_reads_of_page_ = page;
  }
  void FailWritesOfPage(std::optional<uint64_t> page) {
    std::lock_guard lock(mu_);
    fail_writes_of_page_ = page;
  }
  // Fail every write of a page for which `predicate` returns true (nullptr: none). Called under
  // this store's lock: keep it simple (no calls into the store).
  void FailWritesWhere(std::function<bool(uint64_t)> predicate) {
    std::lock_guard lock(mu_);
    fail_writes_where_ = std::move(predicate);
  }
  void FailAllWrites(bool fail) {
    std::lock_guard lock(mu_);
    fail_all_writes_ = fail;
  }
  void FailSync(bool fail) {
    std::lock_guard lock(mu_);
    fail_sync_ = fail;
  }
  // A failing write first stores the first `bytes` bytes of the new data over the old page
  // (a torn write); 0 = failing writes store nothing.
  void SetTornWriteBytes(uint64_t bytes) {
    std::lock_guard lock(mu_);
    torn_write_bytes_ = bytes;
  }
  // Called with the page index at the start of every Read / Write, without any lock held.
  void SetBeforeRead(std::function<void(uint64_t)> hook) {
    std::lock_guard lock(mu_);
    before_read_ = std::move(hook);
  }
  void SetBeforeWrite(std::function<void(uint64_t)> hook) {
    std::lock_guard lock(mu_);
    before_write_ = std::move(hook);
  }

  // --- Counters (all calls, failed ones included) ----------------------------------------------
  uint64_t reads() const {
    std::lock_guard lock(mu_);
    return reads_;
  }
  uint64_t writes() const {
    std::lock_guard lock(mu_);
    return writes_;
  }
  uint64_t failed_reads() const {
    std::lock_guard lock(mu_);
    return failed_reads_;
  }
  uint64_t failed_writes() const {
    std::lock_guard lock(mu_);
    return failed_writes_;
  }

  // --- PageStore -------------------------------------------------------------------------------
  Status Read(uint64_t page, std::span<std::byte> out) override {
    std::function<void(uint64_t)> hook;
    bool fail = false;
    {
      std::lock_guard lock(mu_);
      hook = before_read_;
      ++reads_;
      if (fail_read_countdown_ != 0 && --fail_read_countdown_ == 0) fail = true;
      if (fail_reads_of_page_ && *fail_reads_of_page_ == page) fail = true;
      if (fail) ++failed_reads_;
    }
    if (hook) hook(page);
    if (fail) return IoError("fault injection: read of page " + std::to_string(page) + " failed");
    return inner_->Read(page, out);
  }

  Status Write(uint64_t page, std::span<const std::byte> data) override {
    std::function<void(uint64_t)> hook;
    bool fail = false;
    uint64_t torn = 0;
    {
      std::lock_guard lock(mu_);
      hook = before_write_;
      ++writes_;
      if (fail_write_countdown_ != 0 && --fail_write_countdown_ == 0) fail = true;
      if (fail_every_nth_write_ != 0 && writes_ % fail_every_nth_write_ == 0) fail = true;
      if (fail_writes_of_page_ && *fail_writes_of_page_ == page) fail = true;
      if (fail_writes_where_ && fail_writes_where_(page)) fail = true;
      if (fail_all_writes_) fail = true;
      if (fail) ++failed_writes_;
      torn = torn_write_bytes_;
    }
    if (hook) hook(page);
    if (!fail) return inner_->Write(page, data);
    if (torn > 0 && data.size() == inner_->page_bytes()) {
      // Tear the page: the old bytes with a prefix of the new ones.
      std::vector<std::byte> mixed(data.size());
      if (inner_->Read(page, mixed).ok()) {
        const size_t prefix = static_cast<size_t>(std::min<uint64_t>(torn, data.size()));
        std::copy(data.begin(), data.begin() + static_cast<ptrdiff_t>(prefix), mixed.begin());
        (void)inner_->Write(page, mixed);
      }
    }
    return IoError("fault injection: write of page " + std::to_string(page) + " failed");
  }

  Status Sync() override {
    {
      std::lock_guard lock(mu_);
      if (fail_sync_) return IoError("fault injection: sync failed");
    }
    return inner_->Sync();
  }

 private:
  PageStore* const inner_;
  mutable std::mutex mu_;
  // All guarded by mu_.
  uint64_t fail_read_countdown_ = 0;
  uint64_t fail_write_countdown_ = 0;
  uint64_t fail_every_nth_write_ = 0;
  std::optional<uint64_t> fail_reads_of_page_;
  std::optional<uint64_t> fail_writes_of_page_;
  std::function<bool(uint64_t)> fail_writes_where_;
  bool fail_all_writes_ = false;
  bool fail_sync_ = false;
  uint64_t torn_write_bytes_ = 0;
  std::function<void(uint64_t)> before_read_;
  std::function<void(uint64_t)> before_write_;
  uint64_t reads_ = 0, writes_ = 0, failed_reads_ = 0, failed_writes_ = 0;
};

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_TESTS_PAGING_FAULT_INJECTING_PAGE_STORE_H_
