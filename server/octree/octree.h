// Octree: the paper's multi-channel octree over a bricked mipmap, built incrementally from
// blocks of voxels ("Incremental Construction"). Every node covers a brick of its level
// (BrickGeometry); a node either owns a stored brick in the BrickPool (interior + one-voxel apron,
// channels interleaved) or is represented by its per-channel averages alone (homogeneous, or
// never written: the background). Nodes live in child groups of 8 consecutive ids — the device
// node buffer's layout (node_encoding.h): node id = 8 * group + octant, the root is node 0 in
// the pseudo-group 0, freed groups are reused lowest-first.
//
// Insert(channel, box, data) performs the paper's three steps:
//  1. the block's voxels are copied into every EXISTING level-0 brick whose stored box (with
//     apron) overlaps the block, creating the nodes (always all 8 children) and bricks whose
//     interior it touches; a brick is allocated only when the node gets a value different from
//     its current uniform value (its rounded average; the background for fresh nodes);
//  2. the dirty region is propagated to the root: at level L the dirty region is the parent-voxel
//     cover of level L-1's, and every parent voxel is the integer mean, round half up,
//     (sum + n/2) / n, of its n VALID children (virtual voxels never count), written into every
//     existing level-L brick whose stored box holds it;
//  3. per node and channel min/max/avg (over the node's valid interior voxels) and subtree
//     min/max are updated bottom-up; a COMPLETE node (every valid voxel of its region written at
//     least once in every channel) whose brick is homogeneous in every channel (max - min <=
//     tolerance) drops its brick and keeps its averages; a complete node whose whole subtree is
//     homogeneous also loses its children. Incomplete nodes are never pruned, so with each voxel
//     written once the final structure (per node key: stats, children, brick bytes) is
//     bit-identical for every insertion order and block shape. Node and brick IDS depend on the
//     order of creation and so are not part of that guarantee.
//
// Aprons: a stored brick's apron always equals the neighbouring level-L voxels as currently
// represented: the neighbour's brick interior if it has one, else the rounded average of the
// deepest existing node covering them; virtual voxels hold the background. Allocation initialises
// the apron from the neighbours, writes update every brick storing the voxel, and dropping a brick
// or a subtree rewrites the neighbours' aprons from the new representation. A voxel on a brick
// face is written twice, on an edge 4 times, on a corner 8 times: for 64^3 bricks that is
// 66^3/64^3 - 1 = 9.7 % more voxel writes (and pool bytes) per level, for 32^3 bricks 19.9 %.
//
// Costs: construction is memory-bound; the hot loops are row kernels (octree.cpp) that move
// whole rows with precomputed offsets and compile-time channel strides. An insert may carry
// several channels of one box (Insert(box, blocks)): every brick is then traversed once for all
// of them (each row, a few hundred bytes, gets one short pass per channel while it is in L1).
// Per insert, each voxel is read once from the block and written once into its leaf brick (a new
// brick is initialised in the same pass); step 2 reuses the block itself as level 0 when the
// block is aligned to parent groups; step 3 takes the statistics of the written part of each
// brick from the write pass, per z plane. For an INCOMPLETE node written partially, exact
// per-plane statistics of its brick are kept (PlaneTable, dropped when the node completes), so a
// thin insert (a single plane, as a live acquisition delivers them) costs time proportional to
// what it writes, never a rescan of the whole brick. With OctreeOptions::workers, the bricks of
// each level of an insert are written in parallel (each task writes only its own brick; the node
// table is not modified meanwhile; structure changes, allocation, publication and step 3 stay on
// the inserting thread).
//
// Overwrites: writing a voxel again replaces its value everywhere (it is still "written"). If it
// lands in a node that was already pruned, the node (and missing nodes below it, created from its
// averages) gets a brick initialised from the AVERAGES first; so with a threshold > 0 the pruned
// brick regains the new data but not the old sub-threshold detail. With threshold 0 nothing is
// lost (a pruned brick was exactly constant).
//
// Thread safety: Insert may be called from several threads at once; inserts are serialised
// internally by one mutex (to use several cores, give one insert several channels and a
// WorkerPool). GetNode, ReadBrick, TryReadBrick, stats, PruningError, SubscribeChanges, Save and
// Flush may be called at any time from any thread: the node table is guarded by a shared_mutex
// (readers shared, the inserting thread exclusive for each mutation, never while holding a page
// pin), brick bytes by striped mutexes, and a new brick is published only when it is complete, so
// a reader always sees a consistent node and an untorn brick. Each change-log event is appended
// after its change is visible to readers (as ChangeLog requires).
#ifndef OCTOSCOPE_OCTREE_OCTREE_H_
#define OCTOSCOPE_OCTREE_OCTREE_H_

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <istream>
#include <memory>
#include <mutex>
#include <optional>
#include <ostream>
#include <set>
#include <shared_mutex>
#include <span>
#include <unordered_map>
#include <vector>

#include "octree/brick_geometry.h"
#include "octree/brick_pool.h"
#include "octree/change_log.h"
#include "octree/write_coverage.h"
#include "paging/page_cache.h"
#include "util/result.h"
#include "util/status.h"
#include "util/worker_pool.h"
#include "volume/volume_info.h"

namespace octoscope::octree {

struct OctreeOptions {
  Vec3 brick_size = kDefaultBrickSize;  // Even, >= 2 per axis.
  // Stored sample size: 1 (uint8) or 2 (uint16). 0 = from VolumeInfo::dtype (1 for 8-bit types,
  // else 2). Ignored by the BrickGeometry overload of Create (the geometry says).
  int bytes_per_sample = 0;
  // Homogeneity threshold as a fraction of each channel's value range (paper: 5 %); 0 prunes
  // only exactly constant bricks. Per-channel tolerance = floor(threshold * range).
  double homogeneity_threshold = 0.0;
  // Per-channel value range for the threshold; empty = the stored type's (255 or 65535).
  std::vector<uint32_t> value_range;
  // Per-channel ABSOLUTE tolerances (max - min <= tolerance is homogeneous); when non-empty it
  // overrides threshold and range.
  std::vector<uint32_t> homogeneity_tolerance;
  // Per-channel background value (what not-yet-inserted voxels show); empty = 0.
  std::vector<uint16_t> background;
};

// One channel's samples of a block for Insert: the block's voxels in the stored type
// (bytes_per_sample each, native byte order), x fastest, then y, then z.
struct ChannelBlock {
  int channel = 0;
  std::span<const std::byte> data;
};

// One channel's statistics of a node. For a node with a brick: over the valid interior voxels of
// its brick (avg = integer sum / count). For a node without one: min = max = its uniform value
// and avg its average (exact for pruned nodes, the background for fresh ones).
struct ChannelSummary {
  uint16_t min = 0;
  uint16_t max = 0;
  uint16_t subtree_min = 0;  // Over this node and its non-virtual descendants.
  uint16_t subtree_max = 0;
  double avg = 0.0;
  bool operator==(const ChannelSummary&) const = default;
};

// A consistent copy of one node.
struct NodeSnapshot {
  uint32_t id = 0;
  NodeKey key;
  uint32_t child_group = 0;  // 0 = no children; else children are ids 8*child_group + octant.
  uint32_t brick = 0;        // 0 = no brick (homogeneous / never written / virtual).
  bool is_virtual = false;   // No valid voxel: never has a brick, stores the background.
  bool complete = false;     // Every valid voxel written in every channel.
  std::vector<ChannelSummary> channels;

  bool has_children() const { return child_group != 0; }
  bool has_brick() const { return brick != 0; }
};

struct OctreeStats {
  uint64_t nodes = 0;              // Live nodes, virtual ones included (groups of 8 + root).
  uint64_t bricks = 0;             // Live bricks.
  uint64_t homogeneous_nodes = 0;  // Live non-virtual nodes without a brick.
  uint64_t pool_bytes = 0;         // bricks * brick bytes.
  bool operator==(const OctreeStats&) const = default;
};

class Octree {
 public:
  static constexpr uint32_t kFormatVersion = 1;

  // An empty tree (only the root, storing the background) whose bricks live on `cache`'s pages.
  // `cache` must outlive the octree; its pages are the brick pool (bricks_per_page =
  // page_bytes / brick_bytes; kInvalidArgument when a page cannot hold one brick). Options are
  // validated (kInvalidArgument naming the field).
  static Result<std::unique_ptr<Octree>> Create(const BrickGeometry& geometry,
                                                const OctreeOptions& options,
                                                paging::PageCache* cache);
  // The same for a volume: size and channel count from `info`, brick size and sample size from
  // `options`.
  static Result<std::unique_ptr<Octree>> Create(const volume::VolumeInfo& info,
                                                const OctreeOptions& options,
                                                paging::PageCache* cache);

  ~Octree();
  Octree(const Octree&) = delete;
  Octree& operator=(const Octree&) = delete;

  // Inserts one channel's block: `box` in level-0 voxel coordinates (inside the volume, non-empty),
  // `data` its samples in the stored type (bytes_per_sample each, native byte order), x fastest,
  // then y, then z. kInvalidArgument / kOutOfRange for a bad channel, box or data size; page
  // cache errors (I/O, budget) are passed on — the tree then stays consistent but may lack part
  // of the block (re-inserting it is safe).
  Status Insert(int channel, const Box& box, std::span<const std::byte> data);
  // Inserts several channels' blocks over the same box at once (each channel at most once, in
  // any order): the same result as inserting them one by one, but every brick is written in one
  // pass for all of them. With `workers`, the bricks of each level are written on the pool's
  // threads. Errors as above.
  Status Insert(const Box& box, std::span<const ChannelBlock> blocks,
                WorkerPool* workers = nullptr);

  // The node with this key / id, or nullopt when it does not exist (not created, pruned, id free).
  std::optional<NodeSnapshot> GetNode(const NodeKey& key) const;
  std::optional<NodeSnapshot> GetNode(uint32_t id) const;
  // Copies the stored brick (geometry().brick_bytes() bytes) of node `id`. kNotFound when the node
  // does not exist or has no brick; kInvalidArgument when out.size() != brick_bytes. May wait for
  // a page load (PageCache::Pin). On any error `out` is untouched (DeviceOctree relies on it).
  Status ReadBrick(uint32_t id, std::span<std::byte> out) const;
  // ReadBrick for threads that must never wait for the disk (a render thread): kUnavailable when
  // the brick's page is not in RAM now (nothing copied; *page, when given, says which page to
  // prefetch). Other errors as ReadBrick.
  Status TryReadBrick(uint32_t id, std::span<std::byte> out, uint64_t* page = nullptr) const;
  // The brick pool's page cache (for prefetching the pages TryReadBrick reports).
  paging::PageCache* page_cache() const { return cache_; }

  // A new consumer of the change log (change_log.h): it reports the node changes from now on, or
  // tells the consumer to resynchronise when it fell more than `max_backlog` events behind. Walk
  // the tree (GetNode from the root) after subscribing: earlier changes are not in the log.
  ChangeSubscription SubscribeChanges(size_t max_backlog = kDefaultChangeBacklog) {
    return changes_.Subscribe(max_backlog);
  }
  OctreeStats stats() const;  // O(nodes): scans the node table.
  // Per channel, the largest |voxel - shown value| over every valid voxel the tree represents by
  // an average instead of its own value (a pruned brick or subtree), in stored units: 0 for
  // every channel when the homogeneity tolerance is 0 (lossless). Exact for complete nodes: a
  // pruned node's subtree range is its data's range. O(nodes).
  std::vector<uint32_t> PruningError() const;

  // Writes every dirty brick page back and syncs the store (PageCache::Flush).
  Status Flush();

  // Persists the node table, statistics, completeness and free lists (not the bricks: they are
  // on the page store; Flush() it too). Format: docs/octree_format.md, "Node table".
  Status Save(std::ostream& out) const;
  // Reads what Save wrote; bricks are read from `cache`'s store. Every count and index is
  // validated (kCorrupt naming the problem) before use.
  static Result<std::unique_ptr<Octree>> Load(std::istream& in, paging::PageCache* cache);

  const BrickGeometry& geometry() const { return geometry_; }
  uint32_t tolerance(int channel) const { return tolerance_[channel]; }
  uint16_t background(int channel) const { return background_[channel]; }

 private:
  // Per-node record, 12 bytes (plus 16 bytes of ChannelStats per channel). Invariants for a
  // live node: brick != 0 only for non-virtual nodes; child_group != 0 only for non-virtual nodes
  // at level >= 1, and then group_parent_[child_group] == this id.
  struct NodeRecord {
    uint32_t child_group = 0;
    uint32_t brick = 0;
    uint8_t level = 0;
    uint8_t flags = 0;  // kLive | kVirtual | kComplete.
    uint16_t reserved = 0;
  };
  struct ChannelStats {
    uint16_t min = 0, max = 0, sub_min = 0, sub_max = 0;
    double avg = 0.0;
  };
  // Completeness of a leaf being written: per channel, which voxels were written. Dropped (and
  // the node flagged kComplete) when every channel is complete.
  struct LeafProgress {
    uint64_t complete_channels = 0;  // Bit c: channel c complete.
    std::vector<std::unique_ptr<WriteCoverage>> channels;
  };
  static constexpr uint8_t kLive = 1, kVirtual = 2, kComplete = 4;
  static constexpr uint32_t kFreeGroup = 0xffffffffu;
  static constexpr int kBrickStripes = 64;
  struct Located {
    uint32_t id;
    bool exact;  // The node itself exists (else id is its deepest existing ancestor).
  };
  // Min, max and sum of one channel over some voxels (lo > hi when there were none).
  struct SampleStats {
    uint32_t lo = 0xffffffffu;
    uint32_t hi = 0;
    uint64_t sum = 0;
    void Add(const SampleStats& o) {
      lo = std::min(lo, o.lo);
      hi = std::max(hi, o.hi);
      sum += o.sum;
    }
  };
  // One channel of the block being inserted at some level: uint16 samples laid out over the
  // level's block box, x fastest.
  struct Lane {
    int channel;
    const uint16_t* values;
  };
  using Lanes = std::span<const Lane>;
  // A node whose interior an insert wrote (step 1 or 2), for step 3: `written` is the part of
  // its valid interior now holding the inserted values (empty when the node stayed brickless)
  // and `planes` their statistics per lane and z plane ([lane * written.Extent(2) + z - lo]),
  // gathered while they were hot in cache, so step 3 never rescans what was just written.
  struct Touched {
    uint32_t id = 0;
    Box written;
    std::vector<SampleStats> planes;
  };
  // Exact per-z-plane statistics of the valid interior of an INCOMPLETE node's brick, per
  // channel ([c * planes + z - valid.lo[2]]), kept while the node is being filled in so that a
  // thin insert updates its node's statistics in time proportional to what it wrote (a rescan
  // of the whole brick per plane would cost a brick depth's worth of work per plane). A
  // channel's entries are valid only when its bit in `known` is set. Dropped when the node
  // completes or loses its brick.
  struct PlaneTable {
    uint64_t known = 0;
    std::vector<SampleStats> planes;
  };
  // One node of WriteLevel's work list.
  struct LevelItem {
    NodeKey key;
    uint32_t id = 0;
    uint32_t brick = 0;       // Existing brick, or the one allocated for this insert.
    bool apron_only = false;  // Only the node's apron overlaps the block.
    bool allocate = false;    // A brick is allocated for this insert (published after).
    bool unchanged = false;   // Brickless and the block equals its uniform value.
    Touched touched;
  };

  Octree(const BrickGeometry& geometry, paging::PageCache* cache, uint32_t bricks_per_page);
  static Result<std::unique_ptr<Octree>> CreateImpl(const BrickGeometry& geometry,
                                                    const OctreeOptions& options,
                                                    paging::PageCache* cache);

  // --- Node table (callers: the inserting thread, or readers under a shared lock). ---
  Located Locate(const NodeKey& key) const;
  NodeKey KeyOf(uint32_t id) const;
  ChannelStats& Stat(uint32_t id, int c) { return stats_[static_cast<size_t>(id) * channels_ + c]; }
  const ChannelStats& Stat(uint32_t id, int c) const {
    return stats_[static_cast<size_t>(id) * channels_ + c];
  }
  uint16_t Uniform(uint32_t id, int c) const;
  NodeSnapshot SnapshotLocked(uint32_t id) const;
  bool IsLiveId(uint32_t id) const;

  // --- Mutations (inserting thread only; they take mu_ exclusively themselves). ---
  Result<uint32_t> EnsureNode(const NodeKey& key);
  Status CreateChildren(uint32_t id);
  // Fills the new (unpublished) brick of node `id` so that it shows what the node showed so far,
  // except that the lanes' channels of StoredBox(key) ∩ src_box are written from the lanes
  // (laid out over src_box), gathering the statistics of touched->written. Thread-safe against
  // other InitBrick/PutRegion calls on other bricks of the same level (the parallel phase of
  // WriteLevel: the node table is not modified meanwhile).
  Status InitBrick(uint32_t brick, uint32_t id, const NodeKey& key, Lanes lanes, const Box& src_box,
                   Touched* touched) const;
  Status DropBrick(uint32_t id, const NodeKey& key);
  Status DeleteChildren(uint32_t id, const NodeKey& key);
  Status RefreshAprons(int level, const Box& region);

  // --- Voxel access (inserting thread). Buffers are laid out over a box, x fastest. ---
  Status ReadRepresentation(int level, const Box& box, int c, uint16_t* out) const;
  Status WriteLevel(int level, const Box& box, Lanes lanes, std::vector<Touched>* touched);
  void MarkLeafWritten(uint32_t id, const NodeKey& key, const Box& box, int c);
  Status UpdateNode(const Touched& touched, Lanes lanes);
  // Statistics of channel c of the brick's valid interior plane z, scanned from the brick.
  Result<SampleStats> ScanPlane(uint32_t brick, const NodeKey& key, int c, int64_t z) const;
  // Writes the lanes' channels of `region` of the brick from the lanes (laid out over src_box);
  // with `touched`, gathers the statistics of touched->written (a part of region) as well.
  // Thread-safe for distinct bricks (see InitBrick).
  Status PutRegion(uint32_t brick, const NodeKey& key, const Box& region, Lanes lanes,
                   const Box& src_box, Touched* touched = nullptr) const;
  // Runs fn(i) for i in [0, n) on the workers (or inline).
  Status ForEach(size_t n, const std::function<Status(size_t)>& fn) const;

  std::mutex& BrickLock(uint32_t brick) const { return brick_locks_[brick % kBrickStripes]; }

  BrickGeometry geometry_;
  int channels_ = 1;
  std::vector<uint32_t> tolerance_;
  std::vector<uint16_t> background_;
  paging::PageCache* cache_;
  mutable BrickPool pool_;

  mutable std::mutex insert_mu_;        // Serialises Insert (and Save's view of progress_).
  mutable std::shared_mutex mu_;        // Guards the node table below.
  std::vector<NodeRecord> nodes_;       // 8 per group; group 0 holds only the root (id 0).
  std::vector<ChannelStats> stats_;     // nodes_.size() * channels_.
  std::vector<uint32_t> group_parent_;  // Parent node id per group; kFreeGroup when free.
  std::set<uint32_t> free_groups_;
  std::unordered_map<uint32_t, LeafProgress> progress_;    // Guarded by insert_mu_.
  std::unordered_map<uint32_t, PlaneTable> plane_tables_;  // Guarded by insert_mu_.
  WorkerPool* workers_ = nullptr;  // The current insert's pool (guarded by insert_mu_).

  mutable std::array<std::mutex, kBrickStripes> brick_locks_;
  ChangeLog changes_;
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_OCTREE_H_
