// OctreeCache: an octree persisted in a cache directory, tied to the scan it was built from.
// Files (specified in docs/octree_format.md, "Cache directory"):
//   MANIFEST        what was built from what: format version, state, source identity, volume,
//                   brick size, threshold, value maps, page size, node-table checksum; written
//                   LAST, temp-then-rename with fsync. Its presence with "state complete" is the
//                   only mark of a complete cache; "state checkpoint" marks a checkpoint.
//   octree.pool     the brick pool's pages (paging::FilePageStore).
//   octree.nodes    the node table (Octree::Save), temp-then-rename with fsync.
//   BUILDING        present while a build runs (diagnostics; its absence proves nothing).
//   LOCK            the file a process locks (flock) while it builds or serves the directory.
// A build killed at any moment (SIGKILL, power loss) leaves no complete MANIFEST, so the next
// open detects an incomplete cache and starts over; a complete cache whose source identity and
// build parameters match is reopened without rebuilding anything.
//
// Checkpoints (a resumable build: a live stream, which may pause for days and outlive the
// process): CreateResumable starts one; Checkpoint makes the build so far durable without
// completing it — the pool flushed and fsynced, the node table, the owner's attachments (a
// stream's received planes and histogram) and the pool's shadow map as checkpoint-G.* files,
// then a MANIFEST with "state checkpoint" and generation G, written last; Resume reopens the
// latest checkpoint exclusively for further inserts. Between checkpoints the octree rewrites
// bricks in place and reuses brick ids, so a resumable cache's pool is a
// paging::ShadowPageStore: writes of the pages a checkpoint refers to go to octree.shadow until
// the next checkpoint is durable, and are copied into the pool only then (a crash during the copy
// is finished by Resume from the map stored with the checkpoint). So octree.pool never holds
// anything newer than the latest checkpoint in a page that checkpoint uses, and a crash loses
// only what came after it. MarkDirty records (in DIRTY, durably) that the build changes after
// checkpoint G; Resume and Inspect report a DIRTY of the current generation as an unclean stop:
// whatever the owner added after the checkpoint is gone, and the checkpoint is what it resumes
// from. A checkpoint is never a complete cache: Open refuses the directory (it is neither served
// nor cleared); only Resume goes on with it, and Commit (after a Checkpoint) completes it.
//
// Locking: an OctreeCache holds a lock on its directory for its whole lifetime: shared while it
// serves a complete cache (several processes may), exclusive while it builds one (nobody else may
// use the directory). Open never clears, rebuilds or serves a directory another process holds in
// a conflicting way: it fails at once (kUnavailable, naming the directory) instead of waiting.
// The kernel releases the lock when the process ends, however it ends.
//
// Thread safety: an OctreeCache is used by one owning thread, except MarkDirty (thread-safe; it
// may race with inserts on other threads); the Octree it holds has its own contract (octree.h).
// CacheLock objects are independent of each other.
#ifndef OCTOSCOPE_OCTREE_OCTREE_CACHE_H_
#define OCTOSCOPE_OCTREE_OCTREE_CACHE_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "io/file_gate.h"
#include "octree/octree.h"
#include "paging/page_cache.h"
#include "paging/page_store.h"
#include "paging/shadow_page_store.h"
#include "util/result.h"
#include "volume/value_map.h"
#include "volume/volume_info.h"

namespace octoscope::octree {

// What identifies a scan on disk: a hash over, for each of its files (the input file, or every
// file below an input folder), the path relative to the input, the size, the modification time
// and the first 64 KiB; and the total bytes of those files. Files are read through `gate` (a
// dataset's, for the server): one it refuses is its refusal.
struct SourceIdentity {
  uint64_t hash = 0;
  uint64_t file_bytes = 0;
  bool operator==(const SourceIdentity&) const = default;
};
Result<SourceIdentity> ComputeSourceIdentity(const std::filesystem::path& input,
                                             const io::FileGate& gate = io::FileGate());

// The build parameters a cache must match to be reused.
struct CacheParams {
  volume::VolumeInfo info;  // Size, channels, dtype, series, time.
  Vec3 brick_size = kDefaultBrickSize;
  double threshold = 0.0;  // 0 = lossless.
};

// What a build derives from the data itself (it may need a pass over every voxel): how file
// values map to stored ones, and each channel's stored value range that the homogeneity threshold
// is a fraction of. A reused cache keeps the mapping it was built with (same source, same data).
struct ValueMapping {
  std::vector<volume::ValueMap> value_maps;  // One per channel.
  std::vector<uint32_t> value_range;         // One per channel, in stored units.
};

// The manifest's content (docs/octree_format.md). Parse is strict: unknown keys, missing keys,
// malformed numbers and out-of-range values are kCorrupt; `generation` and `attachment` lines only
// belong to checkpoints (and one `generation` is required there).
struct CacheManifest {
  static constexpr int kVersion = 1;
  enum class State { kComplete, kCheckpoint };
  // A file a checkpoint carries for its owner (checkpoint-G.NAME), checked by its checksum.
  struct Attachment {
    std::string name;       // [a-z]{1,32}.
    uint64_t checksum = 0;  // FNV-1a 64 of its bytes.
    bool operator==(const Attachment&) const = default;
  };
  State state = State::kComplete;
  uint64_t generation = 0;              // Checkpoints: 1, 2, ...; 0 for complete caches.
  std::vector<Attachment> attachments;  // Checkpoints only, in the order given.
  uint64_t shadow_checksum = 0;         // Checkpoints: FNV-1a 64 of checkpoint-G.shadow.
  SourceIdentity source;
  CacheParams params;
  ValueMapping mapping;
  uint64_t page_bytes = 0;
  uint64_t nodes_checksum = 0;  // FNV-1a 64 of octree.nodes (checkpoints: checkpoint-G.nodes).

  std::string Serialize() const;
  static Result<CacheManifest> Parse(std::string_view text);
  // True when a cache built with this manifest serves `source` built with `params`.
  bool Matches(const SourceIdentity& source, const CacheParams& params) const;
};

// An advisory lock (flock(2)) on the LOCK file of a cache directory. Locks are per open file
// description, so two CacheLocks conflict even within one process. Released on destruction.
class CacheLock {
 public:
  enum class Mode { kShared, kExclusive };

  // Takes the lock on `dir`/LOCK (created if missing) without waiting. Errors: kUnavailable,
  // naming `dir` and the holder's pid where known, when another holder's lock conflicts; kIoError
  // when LOCK cannot be opened. A directory where LOCK cannot be created (read-only media) can
  // be shared without a lock: nobody can build into it anyway.
  static Result<std::unique_ptr<CacheLock>> Acquire(const std::filesystem::path& dir, Mode mode);
  ~CacheLock();
  CacheLock(const CacheLock&) = delete;
  CacheLock& operator=(const CacheLock&) = delete;

  Mode mode() const { return mode_; }
  // Converts a shared lock to an exclusive one without waiting. kUnavailable when another holder
  // shares the directory; the lock is then no longer held at all (flock(2) drops it first), so
  // the caller must give up the directory.
  Status MakeExclusive();
  // Converts an exclusive lock to a shared one (a finished build now only serves the directory),
  // so other processes may share it. flock(2) converts by dropping first: should another process
  // take the directory exclusively in that instant, kUnavailable, and nothing is held.
  Status MakeShared();

 private:
  CacheLock(std::filesystem::path dir, int fd, Mode mode)
      : dir_(std::move(dir)), fd_(fd), mode_(mode) {}
  // Records this process as the exclusive holder (its pid in LOCK, for others' messages).
  void RecordHolder();

  std::filesystem::path dir_;
  int fd_ = -1;  // -1: a read-only directory shared without a lock.
  Mode mode_;
};

// The owner's files of a checkpoint, by name ([a-z]{1,32}, unique): their bytes.
using CheckpointAttachments = std::map<std::string, std::string, std::less<>>;

class OctreeCache;

// What Resume found.
struct ResumedCache {
  std::unique_ptr<OctreeCache> cache;  // Holding the directory exclusively, ready for inserts.
  CheckpointAttachments attachments;   // As the checkpoint stored them (checksums verified).
  // The build changed after the checkpoint and was not checkpointed again (the process was
  // killed or crashed): those changes are gone; the tree is the checkpoint's.
  bool unclean = false;
  uint64_t dropped_pages = 0;  // Pool pages written after the checkpoint (their writes are gone).
};

// What a cache directory holds, read without locking or opening anything (Inspect).
struct CacheContents {
  CacheManifest manifest;             // state: complete or checkpoint.
  CheckpointAttachments attachments;  // Checkpoints: the attachments (checksums verified).
  bool unclean = false;               // Checkpoints: as ResumedCache::unclean.
};

class OctreeCache {
 public:
  // Opens the cache in `dir` for `source` + `params` with a page cache of `ram_bytes`:
  // a complete matching cache is loaded (reused() == true, nothing rebuilt, `derive` not called);
  // anything else (no cache, an incomplete one, another source, other parameters) is cleared,
  // `derive` computes the value mapping, and an empty octree is created for building
  // (reused() == false). Never serves an incomplete cache. Reuse holds the directory's lock
  // shared, building holds it exclusive (taken before anything is cleared, after `derive`);
  // kUnavailable when another process holds it in a conflicting way (see above).
  static Result<std::unique_ptr<OctreeCache>> Open(
      const std::filesystem::path& dir, const SourceIdentity& source, const CacheParams& params,
      uint64_t ram_bytes, const std::function<Result<ValueMapping>()>& derive);
  // A fresh resumable cache in `dir` (see "Checkpoints" above) for `source` + `params`, with
  // `mapping`: takes the directory exclusively (kUnavailable when another holder uses it), clears
  // what it held, and starts an empty octree whose pool is shadowed. Nothing is durable until the
  // first Checkpoint.
  static Result<std::unique_ptr<OctreeCache>> CreateResumable(const std::filesystem::path& dir,
                                                              const SourceIdentity& source,
                                                              const CacheParams& params,
                                                              uint64_t ram_bytes,
                                                              ValueMapping mapping);
  // Reopens the checkpoint in `dir` exclusively for further inserts, with a page cache of
  // `ram_bytes`: drops what was written after the checkpoint (the shadow; the pool itself still
  // holds the checkpoint, a copy the checkpoint left unfinished is finished), loads its node table
  // and attachments, and continues with the next generation. Errors: kUnavailable while another
  // holder uses the directory; kFailedPrecondition for a complete cache (finished: nothing to
  // resume); kCorrupt when there is no checkpoint or its files are damaged (naming the file).
  static Result<ResumedCache> Resume(const std::filesystem::path& dir, uint64_t ram_bytes);
  // Reads the MANIFEST (and a checkpoint's attachments) of `dir` without locking or changing
  // anything. kNotFound without a MANIFEST; kCorrupt for a damaged one or damaged attachments.
  static Result<CacheContents> Inspect(const std::filesystem::path& dir);
  ~OctreeCache();

  bool reused() const { return reused_; }
  // Why the cache was (re)built: "new", "incomplete (a build was interrupted)", "source changed",
  // "parameters changed", "unreadable manifest: …"; "" when reused.
  const std::string& rebuild_reason() const { return rebuild_reason_; }
  Octree& octree() { return *octree_; }
  const ValueMapping& mapping() const { return manifest_.mapping; }
  paging::PageCache& page_cache() { return *page_cache_; }
  const std::filesystem::path& dir() const { return dir_; }

  // Makes a finished build durable and complete: flushes and fsyncs the pool, writes the node
  // table, then the MANIFEST (both temp-then-rename + fsync, directory fsynced), removes BUILDING,
  // and then holds the directory's lock SHARED (CacheLock::MakeShared): the complete cache may be
  // served by other processes too.
  // A resumable cache must be checkpointed after its last change first (kFailedPrecondition
  // otherwise: nothing is written); it drops its checkpoint files, shadow and DIRTY marker
  // afterwards.
  Status Commit();

  // Resumable caches only (kFailedPrecondition otherwise). Checkpoint: makes the build so far
  // durable as checkpoint generation()+1 with `attachments` (see "Checkpoints" above); on an
  // error before its MANIFEST the previous checkpoint stays the one Resume finds. Should copying
  // the shadow into the pool fail after the MANIFEST, the cache takes no more changes
  // (MarkDirty fails) until it is reopened with Resume, which finishes the copy.
  // REQUIRES: no insert in flight.
  Status Checkpoint(const CheckpointAttachments& attachments);
  // Records durably (once per checkpoint) that the build is about to change after the current
  // checkpoint; call it before the change. Thread-safe.
  Status MarkDirty();
  // The current checkpoint's generation (0 before the first).
  uint64_t generation() const { return manifest_.generation; }
  // The source identity the cache was built from (or is being built from).
  const SourceIdentity& source() const { return manifest_.source; }

  // Bytes per page for a brick of `brick_bytes`: whole bricks, about 1 MiB (at least one brick).
  static uint64_t PageBytesFor(uint64_t brick_bytes);
  // The fewest pages a page-cache budget must hold (Open refuses smaller budgets).
  static constexpr uint64_t kMinPages = 8;

 private:
  OctreeCache() = default;
  // The geometry and octree options of `params`, and the page size of its pool.
  struct Layout;
  static Result<Layout> LayoutFor(const CacheParams& params);
  // Removes the checkpoint files of generations other than `keep` (0: all of them).
  void RemoveCheckpointFiles(uint64_t keep);

  // Declared first, destroyed last: the lock outlives every file access below.
  std::unique_ptr<CacheLock> lock_;
  std::filesystem::path dir_;
  bool reused_ = false;
  std::string rebuild_reason_;
  CacheManifest manifest_;
  // Destruction order matters: the octree uses the page cache, which uses the store.
  std::unique_ptr<paging::PageStore> store_;
  std::unique_ptr<paging::PageCache> page_cache_;
  std::unique_ptr<Octree> octree_;
  // Resumable caches: the pool's shadow (owned by store_); whether DIRTY was written for the
  // current generation, and whether a checkpoint's copy failed (both guarded by dirty_mu_).
  paging::ShadowPageStore* shadow_ = nullptr;
  std::mutex dirty_mu_;
  bool dirty_ = false;
  bool copy_failed_ = false;
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_OCTREE_CACHE_H_
