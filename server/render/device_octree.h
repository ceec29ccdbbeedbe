// DeviceOctree: the octree mirrored into one OpenCL device's memory (paper, "GPU Data Structure",
// "Brick Upload from RAM to GPU", "Incremental Octree Updates on the GPU") and the brick upload
// manager that decides which bricks are resident.
//
// Device data (layouts: kernels/node_format.h, docs/octree_format.md "Device node buffer"):
//  * NODE BUFFER: one entry per node id (NodeWords(C) uint32 words), kept as a host mirror plus a
//    device buffer. Create() subscribes to the octree's change log (its own cursor; other
//    mirrors and consumers have theirs), then walks the tree. Sync() polls the subscription and
//    rewrites only the entries that changed (created, updated or deleted ids, and the residency
//    bits of nodes whose slot changed), as a few coalesced clEnqueueWriteBuffer ranges; when the
//    mirror fell more than `change_backlog` events behind (the log dropped them), Sync walks the
//    tree again instead and rewrites what differs. The buffer grows (reallocated, contents
//    copied) when the octree uses a higher child group.
//    Invariant: an entry's child group is non-zero only when all 8 children's entries are
//    already written (a parent whose new group appeared after the poll is encoded without
//    children until the group's creation events are polled), so a kernel never follows a
//    group into garbage while construction is inserting.
//  * BRICK BUFFER: `slot_count` slots of one stored brick each, ALWAYS as uint16 samples
//    (device_brick_bytes() = geometry().brick_samples() * 2; uint8 trees are widened on upload),
//    split over at most kMaxBrickAllocations device allocations of `slots_per_allocation` slots
//    each when one allocation would exceed CL_DEVICE_MAX_MEM_ALLOC_SIZE (or the option's cap). Slot
//    s lives in allocation s / slots_per_allocation at brick offset s % slots_per_allocation.
//  * CELL RANGES (render/cell_ranges.h): per slot, the per-channel value ranges of the brick's
//    8^3-voxel cells, then of its 16^3-voxel cells (cell_range_words() uint32 words per slot),
//    computed by Upload from the very bytes it sends and written (one write of the changed
//    slots' span) before the node entries that make those bricks resident; the kernels skip the
//    cells that cannot change a ray.
//  * FEEDBACK, written by the kernels (kernels/raycast.cl):
//      request_flags: one uint per node id; a kernel that wants node n does
//        `if (atomic_xchg(&request_flags[n], frame) != frame)` append n to request_list;
//      request_list: uint [0] = count (may exceed capacity: later appends are dropped),
//        [1 .. capacity] node ids;
//      slot_used: one uint per slot, the frame stamp of the last frame that sampled it (plain
//        stores; races write the same value).
//    BeginFrame() returns a new frame stamp and clears the request count; ReadFeedback() reads
//    the request list and the slot stamps back (only the count and the used prefix are read).
//
// Upload manager (Upload): given requested node ids, it adds each one's ancestors that own a
// brick but are not resident (the "chain"), orders the set COARSE FIRST (higher level first,
// then by id) — except that when the set exceeds the slots that can be filled (free or
// evictable), the requested nodes are kept and only the coarsest ancestors that still fit (so a
// ray front larger than the buffer always progresses) — and uploads as many as the budget allows
// (time, measured around the blocking writes, and an optional brick count). A free slot is used
// first; else the least recently used slot (oldest slot_used stamp, coarse levels evicted last at
// equal stamps) whose stamp is older than `protect_frame` — bricks the in-flight frame sampled are
// never evicted, and a brick uploaded in this call is never evicted by the same call. Evicting
// clears the node's in_buffer bit (its entry is rewritten). Resident bricks whose bytes changed
// (kUpdated of a node that still owns a brick) stay resident showing their previous bytes and are
// re-uploaded FIRST within the budget (no flicker: nothing else changes); a node that lost its
// brick frees its slot.
//
// Reservations (several refinements sharing a small buffer): an Upload with
// UploadBudget::reserve_for = owner (e.g. a view) first releases that owner's previous
// reservation, then reserves the REQUESTED bricks it uploads (not ancestors, not re-uploads) for
// the owner, at most slot_count / (owners + 1) of them (owners = the owners holding reservations,
// this one included; so the others and full frames always keep room). No Upload of another owner
// (or without owner) evicts a reserved slot; the owner's next Upload (after its next pass sampled
// them) or ReleaseReservations(owner) frees them. So a paused refinement ray's next brick
// survives the passes of other views until its own next pass: each of its passes advances.
//
// Transfer (DeviceOctreeOptions::upload_path; docs/octree_format.md "Brick transfer"): a brick is
// copied ONCE by the host, straight from its resident page, and no command blocks per brick.
//  * kMapped (default on CPU devices, whose device memory is host memory): the brick allocations
//    are created with CL_MEM_ALLOC_HOST_PTR; an Upload maps each allocation it writes once
//    (CL_MAP_WRITE, zero-copy there), reads the bricks into their slots and unmaps once at the end.
//  * kStaged (default on GPUs): a pinned staging buffer (CL_MEM_ALLOC_HOST_PTR, mapped for the
//    mirror's life, never itself an argument of a command) receives the bricks; each is sent with
//    a NON-blocking clEnqueueWriteBuffer into its slot (DMA from pinned memory on a GPU) and the
//    host waits once when the staging ring wraps and once at the end of the Upload.
// Brick reads never write their output on failure, so a brick read straight into the slot of its
// eviction victim leaves the victim intact when the read fails. When finishing the transfers or
// writing the cell ranges fails, no brick of that Upload is resident afterwards (their slots are
// freed: their bytes or ranges may not be on the device), and the entries say so.
//
// Brick reads (DeviceOctreeOptions::brick_reads): kBlocking reads with Octree::ReadBrick (may wait
// for the disk: command-line renders); kResidentOnly with Octree::TryReadBrick, which never waits:
// a brick whose page is not in RAM is skipped (UploadStats::unavailable; it stays requested by the
// next frame) and its page is recorded for TakeMissingPages, so the render service can prefetch it
// (render_service.h) while the render thread goes on.
//
// Thread safety: NOT thread-safe. One render thread owns a DeviceOctree (and the device queue it
// enqueues on). The octree may be inserting concurrently on other threads: Sync and Upload read
// it only through its thread-safe GetNode / ReadBrick / TryReadBrick and this mirror's change
// subscription.
#ifndef OCTOSCOPE_RENDER_DEVICE_OCTREE_H_
#define OCTOSCOPE_RENDER_DEVICE_OCTREE_H_

#include <CL/cl.h>

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string_view>
#include <vector>

#include "octree/octree.h"
#include "render/cl_handles.h"
#include "render/device.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::render {

inline constexpr int kMaxBrickAllocations = 4;

// How Upload moves brick bytes to the device (see the file comment, "Transfer").
enum class UploadPath {
  kAuto,    // kMapped on CPU devices, kStaged elsewhere.
  kMapped,  // Map the brick allocations and copy into the slots.
  kStaged,  // Pinned staging buffer + non-blocking writes.
};

// How Upload reads bricks from the octree (see the file comment).
enum class BrickReads {
  kBlocking,      // Octree::ReadBrick: may wait for a page load.
  kResidentOnly,  // Octree::TryReadBrick: pages not in RAM are skipped and recorded.
};

struct DeviceOctreeOptions {
  // Total brick buffer size, rounded down to whole bricks; at least kMinBrickSlots slots and at
  // most the node count the geometry could ever need. Default 512 MiB.
  uint64_t brick_buffer_bytes = uint64_t{512} << 20;
  // Cap for one allocation; 0 = the device's CL_DEVICE_MAX_MEM_ALLOC_SIZE. Tests set it small to
  // exercise the split. kResourceExhausted when kMaxBrickAllocations allocations are not enough.
  uint64_t max_allocation_bytes = 0;
  // Capacity of the request list (ids per frame beyond it are dropped; the next frame asks again).
  uint32_t request_capacity = 65536;
  // How many change-log events the mirror may fall behind between two Syncs before the log drops
  // them and the next Sync walks the whole tree again instead (ChangeLog, "Bound"). Must be > 0.
  size_t change_backlog = octree::kDefaultChangeBacklog;
  BrickReads brick_reads = BrickReads::kBlocking;
  UploadPath upload_path = UploadPath::kAuto;
  // kStaged: bytes of the staging ring (rounded down to whole bricks, at least 2).
  uint64_t staging_bytes = uint64_t{32} << 20;
  // A seam for tests (a failing device): when set, Upload asks it before finishing its brick
  // transfers ("bricks") and before writing the cell ranges ("cells"); a non-OK status stands for
  // that transfer's failure.
  std::function<Status(std::string_view transfer)> transfer_fault;
};
inline constexpr uint32_t kMinBrickSlots = 8;
// What a fresh view preloads (UploadCoarseLevels): 32 MiB is the 1 + 8 coarsest bricks of a
// 3-channel 64^3 tree, or 1 + 8 + 64 of a 1-channel 32^3 one; read in well under a second.
inline constexpr uint64_t kCoarseLevelBytes = uint64_t{32} << 20;

// What one frame asks of the upload manager.
struct UploadBudget {
  double max_ms = 150;         // Stop starting uploads once this much time was spent (>= 1 brick).
  uint64_t max_bricks = 0;     // 0 = no count limit.
  uint32_t protect_frame = 0;  // Slots with slot_used >= this stamp are never evicted.
  // Non-zero: reserve the requested bricks this call uploads for this owner until its next
  // Upload (see "Reservations" in the file comment).
  uint64_t reserve_for = 0;
};

struct UploadStats {
  uint64_t requested = 0;    // Distinct nodes asked for (after adding ancestors).
  uint64_t uploaded = 0;     // Bricks written to the device (re-uploads included).
  uint64_t reuploaded = 0;   // Of which: resident bricks refreshed after construction changed them.
  uint64_t evicted = 0;      // Resident bricks dropped to make room.
  uint64_t deferred = 0;     // Requests left for a later frame (budget or no evictable slot).
  uint64_t unavailable = 0;  // kResidentOnly: bricks skipped because their page is not in RAM.
  uint64_t reserved = 0;     // Of the uploaded bricks: reserved for budget.reserve_for.
  uint64_t bytes = 0;        // Brick bytes written.
  double ms = 0;             // Time spent uploading.
};

struct SyncStats {
  uint64_t changes = 0;          // Change-log events applied.
  uint64_t entries_written = 0;  // Node entries written to the device.
  uint64_t stale_bricks = 0;     // Resident bricks now waiting for a re-upload.
  bool resynchronised = false;   // The mirror had fallen behind the log: it was rebuilt by a walk.
};

class DeviceOctree {
 public:
  // `context` and `octree` must outlive the DeviceOctree. Writes every current node of the tree
  // (the tree may be empty or half built) and uploads nothing else: no brick is resident.
  static Result<std::unique_ptr<DeviceOctree>> Create(const ComputeContext* context,
                                                      octree::Octree* octree,
                                                      const DeviceOctreeOptions& options = {});
  // The most brick-buffer bytes a mirror of `geometry` can use (one slot per node that can ever
  // own a brick, at least kMinBrickSlots): a larger brick_buffer_bytes is clamped to it.
  static uint64_t MaxBrickBufferBytes(const octree::BrickGeometry& geometry);
  ~DeviceOctree();
  DeviceOctree(const DeviceOctree&) = delete;
  DeviceOctree& operator=(const DeviceOctree&) = delete;

  // Applies the octree's changes since the last Sync to the node buffer, or re-walks the tree
  // when the mirror fell too far behind (see the file comment).
  Status Sync(SyncStats* stats = nullptr);

  // A new frame stamp (1, 2, ...; never 0) and an empty request list.
  Result<uint32_t> BeginFrame();
  // Reads the frame's request list (node ids, deduplicated by the kernel's flags, at most
  // request_capacity) and the slot stamps (for LRU). REQUIRES: the frame's kernels finished.
  Result<std::vector<uint32_t>> ReadFeedback();

  // Uploads requested bricks (plus stale resident ones) within `budget` (see the file comment).
  Status Upload(std::span<const uint32_t> requested, const UploadBudget& budget,
                UploadStats* stats = nullptr);
  // Makes every brick of `nodes` (and their ancestors) resident regardless of time, as far as
  // slots allow: for tests and for warming a view. Same eviction rules as Upload.
  Status UploadAll(std::span<const uint32_t> nodes, uint32_t protect_frame,
                   UploadStats* stats = nullptr);

  // Makes the coarsest levels resident, whole levels at a time from the root down, while their
  // bricks together take at most `max_bytes` of the brick buffer and a quarter of its slots: what
  // a view shows before its first frame has asked for anything (full frames fall back to a
  // resident ancestor up to two levels above the wanted node). Reads as Upload does (kResidentOnly
  // skips and records pages not in RAM, for TakeMissingPages). Evicts nothing (fills free slots
  // only): meant for a fresh mirror, before its first frame.
  Status UploadCoarseLevels(uint64_t max_bytes, UploadStats* stats = nullptr);

  // Frees the slots reserved for `owner` (e.g. when its refinement ends); they stay resident.
  void ReleaseReservations(uint64_t owner);
  // kResidentOnly: the distinct pages of the bricks Upload skipped since the last call, in the
  // order first seen (then forgotten).
  std::vector<uint64_t> TakeMissingPages();

  // Re-sizes the brick buffer to `brick_buffer_bytes` (rounded and clamped as in Create). When the
  // slot count changes, every brick becomes non-resident (entries rewritten), reservations end,
  // and the old device buffers are released BEFORE the new ones are allocated (the device never
  // holds both); the next frames upload what they need again. Errors (kResourceExhausted, device
  // errors) leave the mirror without brick buffer: it must then be destroyed.
  Status ResizeBrickBuffer(uint64_t brick_buffer_bytes);

  // --- For kernels: bind these as arguments (node buffer and request flags may be reallocated
  // by Sync when the tree outgrows the capacity: re-bind after every Sync). ---
  cl_mem node_buffer() const;
  // kMaxBrickAllocations handles; unused ones repeat allocation 0 (always a valid buffer).
  std::array<cl_mem, kMaxBrickAllocations> brick_buffers() const;
  uint32_t slots_per_allocation() const { return slots_per_allocation_; }
  cl_mem request_flags() const;
  cl_mem request_list() const;
  uint32_t request_capacity() const { return request_capacity_; }
  cl_mem slot_used() const;
  // Cell ranges: slot s's words start at s * cell_range_words().
  cl_mem cell_ranges() const;
  uint64_t cell_range_words() const;

  // --- Introspection (tests, stats). ---
  const octree::Octree& octree() const { return *octree_; }
  const octree::BrickGeometry& geometry() const { return octree_->geometry(); }
  uint32_t slot_count() const { return slot_count_; }
  // Device bytes of the brick buffer (slot_count * device_brick_bytes) and of all the mirror's
  // buffers (brick, node, cell range, feedback buffers).
  uint64_t brick_buffer_bytes() const;
  uint64_t device_bytes() const;
  // Slots reserved now (all owners).
  uint64_t reserved_slots() const;
  int allocation_count() const;
  uint64_t resident_bricks() const;
  // The slot of node `id` when its brick is resident.
  std::optional<uint32_t> SlotOf(uint32_t id) const;
  // The host mirror of the node buffer (what the device holds after the last Sync/Upload).
  std::span<const uint32_t> node_mirror() const;
  uint64_t total_uploaded() const { return total_uploaded_; }
  // Entries of the node buffer (and uints of request_flags): node ids below it are addressable.
  uint64_t node_capacity() const;
  // The stamp BeginFrame last returned (0 before the first frame).
  uint32_t frame() const;
  // Bytes of one slot on the device: brick_samples() * 2 (uint16 samples whatever the tree's).
  uint64_t device_brick_bytes() const;
  // The transfer Upload uses (never kAuto).
  UploadPath upload_path() const;
  // Host copy of the slot stamps (slot_used) as of the last ReadFeedback / Upload.
  std::span<const uint32_t> slot_stamps() const;

 private:
  struct Impl;
  DeviceOctree() = default;
  // Creates `slot_count` slots' brick buffers (split as the file comment says) and the slot
  // state; REQUIRES: no brick buffer.
  Status AllocateBricks(uint64_t brick_buffer_bytes, uint64_t max_allocation_bytes);

  std::unique_ptr<Impl> impl_;
  octree::Octree* octree_ = nullptr;
  uint32_t slot_count_ = 0;
  uint32_t slots_per_allocation_ = 0;
  uint32_t request_capacity_ = 0;
  uint64_t max_allocation_bytes_ = 0;  // DeviceOctreeOptions::max_allocation_bytes.
  uint64_t total_uploaded_ = 0;
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_DEVICE_OCTREE_H_
