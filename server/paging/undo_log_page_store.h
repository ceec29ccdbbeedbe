// UndoLogPageStore: a PageStore whose pages can be put back exactly as they were at the last
// checkpoint after a crash — for a store that is modified in place between checkpoints (a live
// stream's brick pool: bricks are rewritten and brick ids reused). It wraps another store and, the
// first time a PROTECTED page (one below the checkpoint's page count) is written after the
// checkpoint, first appends the page's old content (its before-image, read from the wrapped store)
// to an undo log file and fsyncs the log; only then is the page written in place. Pages at or
// beyond the checkpoint's page count held nothing the checkpoint refers to and are not logged.
//
// After a crash, RollBack puts every logged before-image back, so the store again holds exactly
// what it held at the checkpoint (whatever was written, torn or reused since). A checkpoint (the
// owner's: store synced, its own metadata durable) calls Restart, which empties the log and
// protects every page written so far.
//
// Log file (docs/octree_format.md, "Undo log"), integers little-endian: a 40-byte header — the 8
// bytes "OCTOUNDO", u32 version (1), u32 0, u64 generation, u64 page bytes, u64 FNV-1a 64 of the
// 32 bytes before it — then entries: u64 page index, the page's bytes, u64 FNV-1a 64 of the
// generation, the index and the bytes (so entries of an earlier log never pass for this one's).
// An entry is durable before its page is overwritten, so a crash leaves at most a
// torn LAST entry, whose page was not touched yet; RollBack stops at the first entry that is short
// or fails its checksum. The generation ties a log to its checkpoint: a log of another generation
// (its checkpoint was superseded before the log was restarted) is ignored.
//
// Costs: one read of the old page, one append and one fdatasync per protected page and
// checkpoint interval (the first write only); unprotected pages and later writes cost nothing.
//
// Thread safety: as PageStore (thread-safe). Writes of different pages may race; the log appends
// are serialised. Restart must not run concurrently with Write (the owner quiesces writers).
#ifndef OCTOSCOPE_PAGING_UNDO_LOG_PAGE_STORE_H_
#define OCTOSCOPE_PAGING_UNDO_LOG_PAGE_STORE_H_

#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <set>
#include <span>

#include "paging/page_store.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::paging {

class UndoLogPageStore final : public PageStore {
 public:
  // Wraps `inner` with a fresh undo log at `log_path` for checkpoint `generation`: the pages
  // [0, inner->page_count()) are protected. REQUIRES: `inner` holds exactly the checkpoint's
  // pages (synced, or rolled back with RollBack).
  static Result<std::unique_ptr<UndoLogPageStore>> Create(std::unique_ptr<PageStore> inner,
                                                          const std::filesystem::path& log_path,
                                                          uint64_t generation);
  // Puts the before-images of the log at `log_path` back into `store` when the log belongs to
  // `generation` and to pages of store->page_bytes(), then syncs the store. Returns how many pages
  // were restored: 0 when the log is missing, empty, of another generation or page size. Errors:
  // the store's or the file system's (kIoError).
  static Result<uint64_t> RollBack(PageStore& store, const std::filesystem::path& log_path,
                                   uint64_t generation);

  ~UndoLogPageStore() override;
  UndoLogPageStore(const UndoLogPageStore&) = delete;
  UndoLogPageStore& operator=(const UndoLogPageStore&) = delete;

  // A new checkpoint `generation`: every page written so far belongs to it. Empties the log (a
  // new header, fsynced) and protects [0, page_count()). REQUIRES: the store was synced after its
  // last write, and the owner made the checkpoint durable before calling this.
  Status Restart(uint64_t generation);
  // Before-images logged since the last Create / Restart.
  uint64_t logged_pages() const;

  uint64_t page_bytes() const override { return inner_->page_bytes(); }
  uint64_t page_count() const override { return inner_->page_count(); }
  Status Read(uint64_t page, std::span<std::byte> out) override { return inner_->Read(page, out); }
  Status Write(uint64_t page, std::span<const std::byte> data) override;
  Status Sync() override { return inner_->Sync(); }

 private:
  UndoLogPageStore(std::unique_ptr<PageStore> inner, std::filesystem::path log_path, int fd)
      : inner_(std::move(inner)), log_path_(std::move(log_path)), fd_(fd) {}
  // Truncates the log to a header of `generation`, fsynced. REQUIRES: mu_ held.
  Status StartLogLocked(uint64_t generation);
  // Logs the before-image of `page` unless it is unprotected or logged already.
  Status SaveBeforeImage(uint64_t page);

  const std::unique_ptr<PageStore> inner_;
  const std::filesystem::path log_path_;
  const int fd_;
  mutable std::mutex mu_;  // Guards the log file's end and the fields below.
  uint64_t generation_ = 0;
  uint64_t protected_ = 0;     // Pages [0, protected_) are logged before their first write.
  uint64_t log_bytes_ = 0;     // Where the next entry goes.
  std::set<uint64_t> logged_;  // Protected pages whose before-image is in the log.
};

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_PAGING_UNDO_LOG_PAGE_STORE_H_
