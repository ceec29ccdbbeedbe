// ShadowPageStore: a PageStore whose pages stay exactly as they were at the last checkpoint until
// the next one is durable — for a store its owner keeps modifying in place between checkpoints (a
// live stream's brick pool: bricks are rewritten and brick ids reused). It wraps another store
// (the pool). Pages below the checkpoint's page count are PROTECTED: a write of one goes to a
// slot of the shadow file instead (the same slot for every later write of that page), and reads
// of it come from there; other pages are written through. So whatever happens between two
// checkpoints, the pool itself still holds the last checkpoint's protected pages, and a crash
// loses only the shadow (which is then ignored).
//
// A checkpoint is two steps around the owner's commit point (its MANIFEST):
//   1. Sync, then Freeze: the map of the shadowed pages (page -> slot, and the shadow's
//      generation), which the owner stores durably with its checkpoint;
//   2. after the commit point, Apply: copies the shadowed pages into the pool, syncs it, and
//      starts an empty shadow of the next generation protecting every page written so far.
// A crash between the commit point and the end of Apply leaves the new checkpoint with a shadow
// it has not (entirely) copied: Recover, given the map stored with that checkpoint, copies it
// again (only when the shadow file still is of the map's generation — else the copy was
// complete and the shadow holds later writes, which are dropped).
//
// Shadow file (docs/octree_format.md, "Shadow pages"), integers little-endian: a 40-byte header —
// the 8 bytes "OCTOSHDW", u32 version (1), u32 0, u64 generation, u64 page bytes, u64 FNV-1a 64 of
// the 32 bytes before it — then slot i at byte 40 + i * page bytes.
//
// Costs: a protected page's first write after a checkpoint takes a new slot, later writes reuse
// it (no extra I/O, no fsync of its own); a checkpoint copies the shadowed pages once and syncs
// the shadow and the pool once each.
//
// Thread safety: as PageStore (thread-safe; the PageCache never reads and writes one page at
// once). Freeze and Apply must not run concurrently with Write (the owner quiesces writers).
#ifndef OCTOSCOPE_PAGING_SHADOW_PAGE_STORE_H_
#define OCTOSCOPE_PAGING_SHADOW_PAGE_STORE_H_

#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <string_view>

#include "paging/page_store.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::paging {

// Which page lives in which slot of a shadow file of `generation`.
struct ShadowMap {
  uint64_t generation = 0;
  uint64_t page_bytes = 0;
  std::map<uint64_t, uint64_t> slots;  // Page -> slot.

  // "OCTOSMAP", u32 version (1), u32 0, u64 generation, u64 page bytes, u64 count, then count
  // (u64 page, u64 slot) pairs in page order (little-endian).
  std::string Serialize() const;
  // Strict: kCorrupt for damage, repeated or unordered pages, a slot out of range.
  static Result<ShadowMap> Parse(std::string_view bytes);
  bool operator==(const ShadowMap&) const = default;
};

class ShadowPageStore final : public PageStore {
 public:
  // Wraps `inner` with an empty shadow file at `shadow_path` of `generation`: the pages
  // [0, inner->page_count()) are protected. REQUIRES: `inner` holds exactly the checkpoint's
  // pages (synced, or recovered with Recover).
  static Result<std::unique_ptr<ShadowPageStore>> Create(std::unique_ptr<PageStore> inner,
                                                         const std::filesystem::path& shadow_path,
                                                         uint64_t generation);
  // Finishes the copy a checkpoint with `map` may have left unfinished: when the shadow file at
  // `shadow_path` is of map.generation (and of inner's page size), copies its mapped pages into
  // `inner` and syncs it. Returns how many pages were copied (0: the copy was complete, or there
  // is nothing to copy). kCorrupt when the shadow is of the map's generation but too short.
  static Result<uint64_t> Recover(PageStore& inner, const std::filesystem::path& shadow_path,
                                  const ShadowMap& map);
  // The pages the shadow file at `shadow_path` holds for writes after checkpoint `generation`
  // (0 when it is of another generation or missing): what a crash after that checkpoint dropped.
  static uint64_t PagesWrittenSince(const std::filesystem::path& shadow_path, uint64_t generation);

  ~ShadowPageStore() override;
  ShadowPageStore(const ShadowPageStore&) = delete;
  ShadowPageStore& operator=(const ShadowPageStore&) = delete;

  // Checkpoint step 1: the shadow's map now. REQUIRES: Sync() since the last Write.
  ShadowMap Freeze() const;
  // Checkpoint step 2, after the owner made its checkpoint (with Freeze's map) durable: copies
  // the shadowed pages into the wrapped store, syncs it, and starts an empty shadow of
  // `generation` protecting [0, page_count()).
  Status Apply(uint64_t generation);
  // Protected pages written since the last Create / Apply.
  uint64_t shadowed_pages() const;

  uint64_t page_bytes() const override { return inner_->page_bytes(); }
  uint64_t page_count() const override { return inner_->page_count(); }
  Status Read(uint64_t page, std::span<std::byte> out) override;
  Status Write(uint64_t page, std::span<const std::byte> data) override;
  Status Sync() override;

 private:
  ShadowPageStore(std::unique_ptr<PageStore> inner, std::filesystem::path shadow_path, int fd)
      : inner_(std::move(inner)), shadow_path_(std::move(shadow_path)), fd_(fd) {}
  // Truncates the shadow to an empty one of `generation`, synced. REQUIRES: mu_ held.
  Status StartLocked(uint64_t generation);

  const std::unique_ptr<PageStore> inner_;
  const std::filesystem::path shadow_path_;
  const int fd_;
  mutable std::mutex mu_;  // Guards the fields below (not held during I/O of a page).
  uint64_t generation_ = 0;
  uint64_t protected_ = 0;  // Pages [0, protected_) are shadowed when written.
  std::map<uint64_t, uint64_t> slots_;
};

}  // namespace octoscope::paging

#endif  // OCTOSCOPE_PAGING_SHADOW_PAGE_STORE_H_
