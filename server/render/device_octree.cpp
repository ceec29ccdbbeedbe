#include "render/device_octree.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <limits>
#include <set>
#include <string>
#include <tuple>
#include <unordered_map>
#include <unordered_set>
#include <utility>

#include "octree/node_encoding.h"
#include "render/cell_ranges.h"
#include "render/cl_call.h"

namespace octoscope::render {

namespace {

constexpr uint32_t kNoNode = std::numeric_limits<uint32_t>::max();
// Dirty entries closer than this many ids are written as one range (fewer, larger transfers).
constexpr uint64_t kCoalesceGap = 16;

// Nodes of `geometry` that can ever own a brick: the non-virtual nodes of every level.
uint64_t MaxBrickNodes(const octree::BrickGeometry& geometry) {
  uint64_t count = 0;
  for (int level = 0; level <= geometry.root_level(); ++level) {
    count += geometry.NonVirtualNodes(level).VoxelCount();
  }
  return count;
}

// Bytes of one slot: uint16 samples whatever the tree stores.
uint64_t DeviceBrickBytes(const octree::BrickGeometry& geometry) {
  return geometry.brick_samples() * 2;
}

// The slots of a brick buffer of `bytes`: whole bricks, at least kMinBrickSlots, at most what the
// tree could ever hold (and addressable by a uint32 slot word).
uint64_t SlotsFor(const octree::BrickGeometry& geometry, uint64_t bytes) {
  const uint64_t wanted = bytes / DeviceBrickBytes(geometry);
  const uint64_t most =
      std::max<uint64_t>(kMinBrickSlots, std::min<uint64_t>(MaxBrickNodes(geometry), kNoNode - 1));
  return std::clamp<uint64_t>(wanted, kMinBrickSlots, most);
}

}  // namespace

// All state of a DeviceOctree. Invariants:
//  * live[id] == 1 exactly for the ids whose entry in `mirror` encodes a node (written from a
//    snapshot of a live node); every other entry is all zero.
//  * An entry's child group g is non-zero only when live[8g .. 8g+7] are all 1 with
//    key_of[8g + o] == ChildKey(entry's key, o), and then group_owner[g] is that entry's id.
//  * slot_of[id] == s  <=>  slot_node[s] == id; such an id is live and its entry has in_buffer
//    set with slot s. Free slots are in free_slots and have slot_node == kNoNode.
struct DeviceOctree::Impl {
  const ComputeContext* cc = nullptr;
  octree::Octree* tree = nullptr;
  int channels = 1;
  size_t words = 4;  // NodeWords(channels).
  int bytes_per_sample = 2;
  uint64_t device_brick_bytes = 0;  // brick_samples * 2: the device always holds uint16.

  // --- Node buffer. ---
  std::vector<uint32_t> mirror;         // capacity_nodes() * words.
  std::vector<uint8_t> live;            // Per node id.
  std::vector<octree::NodeKey> key_of;  // Per node id: the key its live entry was written for.
  ClMem node_buffer;
  bool realloc_nodes = true;  // The device buffer must be (re)created from the whole mirror.
  std::vector<uint32_t> dirty;
  std::vector<uint8_t> is_dirty;
  std::set<uint32_t> retry;                            // Encoded childless; re-encode next Sync.
  std::unordered_map<uint32_t, uint32_t> group_owner;  // Mirrored child group -> parent id.
  std::set<uint32_t> to_encode;                        // Ids to (re-)encode in this pass.
  std::unordered_map<uint32_t, octree::NodeSnapshot> snapshots;  // Read during this pass.
  octree::ChangeSubscription changes;  // This mirror's cursor into the octree's change log.

  // --- Brick buffer. ---
  std::vector<ClMem> bricks;
  uint32_t slots_per_allocation = 1;
  std::vector<uint32_t> slot_node;
  std::vector<octree::NodeKey> slot_key;
  std::vector<uint32_t> slot_used;   // Host copy of the stamps (max of upload frame, device).
  std::vector<uint32_t> free_slots;  // Stack; the lowest slot on top.
  std::unordered_map<uint32_t, uint32_t> slot_of;
  std::set<uint32_t> stale;
  std::vector<uint64_t> slot_owner;                 // Per slot: reserved for this owner; 0 none.
  std::unordered_map<uint64_t, uint32_t> reserved;  // Owner -> slots reserved for it (> 0).
  std::vector<std::byte> raw;  // One stored brick of a uint8 tree as ReadBrick gives it.

  // --- Cell ranges (render/cell_ranges.h): per slot, cell_words words; the host mirror is
  // computed from each brick's device bytes as it is uploaded and written after its bricks. ---
  uint64_t cell_words = 0;
  CellRangeScratch cell_scratch;
  std::vector<uint32_t> cell_mirror;  // slot_count * cell_words.
  ClMem cell_ranges_buffer;
  uint32_t cells_dirty_lo = 0;  // Slots [lo, hi) whose mirror changed since the last write.
  uint32_t cells_dirty_hi = 0;

  // --- Transfer (header, "Transfer"). ---
  bool mapped_path = false;
  std::vector<std::byte*> mapped;  // kMapped: per allocation, its mapping during an Upload.
  ClMem staging;                   // kStaged: the pinned ring, mapped for the mirror's life.
  std::byte* staging_ptr = nullptr;
  uint64_t staging_bricks = 0;
  uint64_t staging_next = 0;  // Ring bricks in use since the last wait.

  // --- Feedback. ---
  ClMem request_flags;
  ClMem request_list;
  ClMem slot_used_buffer;
  uint32_t request_capacity = 0;
  uint32_t frame = 0;

  // --- Non-blocking reads (BrickReads::kResidentOnly). ---
  bool resident_only = false;
  std::function<Status(std::string_view)> transfer_fault;  // DeviceOctreeOptions'.
  std::vector<uint64_t> missing_pages;  // Pages of skipped bricks, in first-seen order.
  std::unordered_set<uint64_t> missing_seen;

  uint64_t capacity_nodes() const { return live.size(); }
  std::span<uint32_t> Entry(uint32_t id) {
    return std::span(mirror).subspan(static_cast<size_t>(id) * words, words);
  }

  void MarkDirty(uint32_t id) {
    if (is_dirty[id] == 0) {
      is_dirty[id] = 1;
      dirty.push_back(id);
    }
  }

  // Makes room for node `id` in the host mirror (the device buffer follows at Flush).
  void EnsureCapacity(uint32_t id) {
    if (id < capacity_nodes()) return;
    // Grow by half again at least, so a growing tree reallocates O(log n) times.
    const uint64_t old_groups = capacity_nodes() / 8;
    const uint64_t needed_groups = uint64_t{id} / 8 + 1;
    const uint64_t groups = std::max({needed_groups, old_groups + old_groups / 2, uint64_t{2}});
    const uint64_t nodes = std::min<uint64_t>(groups * 8, uint64_t{kNoNode} + 1);
    mirror.resize(nodes * words, 0);
    live.resize(nodes, 0);
    key_of.resize(nodes);
    is_dirty.resize(nodes, 0);
    realloc_nodes = true;
  }

  // Rewrites the residency bits of `id`'s entry from slot_of.
  void WriteResidency(uint32_t id) {
    if (id >= capacity_nodes() || live[id] == 0) return;
    std::span<uint32_t> entry = Entry(id);
    const auto it = slot_of.find(id);
    entry[0] &= ~octree::kNodeInBufferBit;
    entry[1] = 0;
    if (it != slot_of.end()) {
      entry[0] |= octree::kNodeInBufferBit | octree::kNodeHasBrickBit;
      entry[1] = it->second;
    }
    MarkDirty(id);
  }

  // Ends the reservation of `slot` (if any).
  void Unreserve(uint32_t slot) {
    const uint64_t owner = slot_owner[slot];
    if (owner == 0) return;
    slot_owner[slot] = 0;
    if (const auto it = reserved.find(owner); it != reserved.end() && --it->second == 0) {
      reserved.erase(it);
    }
  }

  // Empties `slot` (its node's entry loses in_buffer); with `to_free_list` it becomes free.
  void ReleaseSlot(uint32_t slot, bool to_free_list) {
    const uint32_t id = slot_node[slot];
    if (id == kNoNode) return;
    Unreserve(slot);
    slot_node[slot] = kNoNode;
    slot_of.erase(id);
    stale.erase(id);
    WriteResidency(id);
    if (to_free_list) free_slots.push_back(slot);
  }

  // Node `id` is not live (any more): zero its entry, free its slot, and re-encode the parent
  // whose mirrored child group contains it (that group is no longer fully written).
  void NodeGone(uint32_t id) {
    if (id >= capacity_nodes()) return;
    if (const auto it = slot_of.find(id); it != slot_of.end()) ReleaseSlot(it->second, true);
    stale.erase(id);
    retry.erase(id);
    snapshots.erase(id);
    if (live[id] == 0) return;
    if (id != 0) {
      if (const auto it = group_owner.find(id / 8); it != group_owner.end())
        to_encode.insert(it->second);
    }
    const uint32_t group = octree::Word0ChildGroup(Entry(id)[0]);
    if (group != 0) {
      if (const auto it = group_owner.find(group); it != group_owner.end() && it->second == id) {
        group_owner.erase(it);
      }
    }
    live[id] = 0;
    const std::span<uint32_t> entry = Entry(id);
    std::fill(entry.begin(), entry.end(), 0u);
    MarkDirty(id);
  }

  // Writes `snap` (a live node) into its entry, enforcing the child-group invariant.
  void Encode(const octree::NodeSnapshot& snap) {
    const uint32_t id = snap.id;
    // A resident brick stays only while the node still owns a brick at the same key (an id
    // reused for another node after a delete must not show the old node's brick).
    if (const auto it = slot_of.find(id); it != slot_of.end()) {
      if (!snap.has_brick() || !(slot_key[it->second] == snap.key)) ReleaseSlot(it->second, true);
    }
    uint32_t group = snap.child_group;
    if (group != 0) {
      // Point at the group only once all 8 children are written in the mirror AS THIS NODE'S
      // children: a reused group whose old children's deletions are not polled yet still looks
      // live, but for another parent's keys.
      bool all_live = uint64_t{group} * 8 + 7 < capacity_nodes();
      for (uint32_t o = 0; all_live && o < 8; ++o) {
        all_live = live[group * 8 + o] != 0 &&
                   key_of[group * 8 + o] == octree::ChildKey(snap.key, static_cast<int>(o));
      }
      if (!all_live) group = 0;
    }
    if (group == 0 && snap.child_group != 0) {
      retry.insert(id);
    } else {
      retry.erase(id);
    }
    const uint32_t old_group = octree::Word0ChildGroup(Entry(id)[0]);
    if (old_group != 0 && old_group != group) {
      if (const auto it = group_owner.find(old_group);
          it != group_owner.end() && it->second == id) {
        group_owner.erase(it);
      }
    }
    if (group != 0) group_owner[group] = id;
    octree::DeviceNode node;
    node.has_brick = snap.has_brick();
    node.child_group = group;
    if (const auto it = slot_of.find(id); it != slot_of.end()) {
      node.in_buffer = true;
      node.brick_slot = it->second;
    }
    node.averages.reserve(snap.channels.size());
    for (const octree::ChannelSummary& c : snap.channels) {
      node.averages.push_back(octree::QuantizeAverage(c.avg, bytes_per_sample));
      // The subtree's range (uint8 trees: the same numbers, widened like the bricks).
      const bool valid = c.subtree_min <= c.subtree_max;  // Else: nothing is skipped.
      node.range_min.push_back(valid ? c.subtree_min : uint16_t{0});
      node.range_max.push_back(valid ? c.subtree_max : uint16_t{0xffff});
    }
    // Cannot fail: the entry has NodeWords(channels) words and the group is a 30-bit index.
    (void)octree::EncodeNode(node, Entry(id));
    live[id] = 1;
    key_of[id] = snap.key;
    MarkDirty(id);
  }

  // Encodes every id in `to_encode` (and the pending retries) from its snapshot of this pass or a
  // fresh read.
  void EncodePending() {
    to_encode.insert(retry.begin(), retry.end());
    while (!to_encode.empty()) {
      const uint32_t id = *to_encode.begin();
      to_encode.erase(to_encode.begin());
      if (id >= capacity_nodes() || live[id] == 0) continue;
      std::optional<octree::NodeSnapshot> snap;
      if (const auto it = snapshots.find(id); it != snapshots.end()) {
        snap = std::move(it->second);
        snapshots.erase(it);
      } else {
        snap = tree->GetNode(id);
      }
      if (!snap.has_value()) {
        NodeGone(id);
        continue;
      }
      Encode(*snap);
    }
    snapshots.clear();
  }

  // Reads every node reachable from the root now (by child group) into `snapshots`. A node
  // deleted while we walk is skipped, a group reused meanwhile may be reached twice (read once):
  // the events of both follow at the next poll.
  void WalkTree() {
    std::vector<uint32_t> queue = {0};
    for (size_t i = 0; i < queue.size(); ++i) {
      if (snapshots.count(queue[i]) != 0) continue;
      std::optional<octree::NodeSnapshot> snap = tree->GetNode(queue[i]);
      if (!snap.has_value()) continue;
      if (snap->has_children()) {
        for (uint32_t o = 0; o < 8; ++o) queue.push_back(snap->child_group * 8 + o);
      }
      snapshots.emplace(snap->id, std::move(*snap));
    }
  }

  // Marks every walked node live with its key and queues it for encoding (after WalkTree).
  void TakeWalk() {
    for (const auto& [id, snap] : snapshots) {
      EnsureCapacity(id);
      live[id] = 1;
      key_of[id] = snap.key;
      to_encode.insert(id);
    }
  }

  // The subscription fell behind and events were dropped: make the mirror equal to the tree
  // again from a fresh walk. Entries the walk did not reach are gone (or their creation events
  // follow); resident bricks that still belong to their node may have changed unseen, so they
  // are re-uploaded first like stale ones (still showing their previous bytes meanwhile).
  void Resynchronise() {
    WalkTree();
    for (uint64_t id = 0; id < capacity_nodes(); ++id) {
      if (live[id] != 0 && snapshots.count(static_cast<uint32_t>(id)) == 0) {
        NodeGone(static_cast<uint32_t>(id));
      }
    }
    for (const auto& [id, snap] : snapshots) {
      if (const auto it = slot_of.find(id);
          it != slot_of.end() && snap.has_brick() && slot_key[it->second] == snap.key) {
        stale.insert(id);
      }
    }
    TakeWalk();
  }

  // Sends the dirty entries to the device (or the whole mirror into a new buffer after growth).
  Status Flush(uint64_t* entries_written) {
    if (realloc_nodes) {
      OCTO_ASSIGN_OR_RETURN(ClMem nodes,
                            cc->CreateBuffer(CL_MEM_READ_WRITE, mirror.size() * 4, mirror.data()));
      OCTO_ASSIGN_OR_RETURN(ClMem flags, cc->CreateBuffer(CL_MEM_READ_WRITE, capacity_nodes() * 4));
      OCTO_RETURN_IF_ERROR(Fill(flags, capacity_nodes() * 4));
      node_buffer = std::move(nodes);
      request_flags = std::move(flags);
      realloc_nodes = false;
      for (uint32_t id : dirty) is_dirty[id] = 0;
      dirty.clear();
      if (entries_written != nullptr) *entries_written += capacity_nodes();
      return Status::Ok();
    }
    std::sort(dirty.begin(), dirty.end());
    // Coalesce near ranges: one transfer per run of dirty ids with small gaps.
    size_t i = 0;
    while (i < dirty.size()) {
      size_t j = i + 1;
      while (j < dirty.size() && dirty[j] - dirty[j - 1] <= kCoalesceGap) ++j;
      const uint64_t first = dirty[i];
      const uint64_t count = uint64_t{dirty[j - 1]} - first + 1;
      OCTO_RETURN_IF_ERROR(cc->WriteBuffer(node_buffer, first * words * 4, count * words * 4,
                                           mirror.data() + first * words));
      i = j;
    }
    if (entries_written != nullptr) *entries_written += dirty.size();
    for (uint32_t id : dirty) is_dirty[id] = 0;
    dirty.clear();
    return Status::Ok();
  }

  ~Impl() {
    // Destructors never throw: a failure is logged.
    if (staging_ptr != nullptr) {
      ClLogError(
          clEnqueueUnmapMemObject(cc->queue(), staging.get(), staging_ptr, 0, nullptr, nullptr),
          "clEnqueueUnmapMemObject(staging)");
      ClLogError(clFinish(cc->queue()), "clFinish");
    }
  }

  uint64_t SlotsIn(uint32_t allocation) const {
    return std::min<uint64_t>(slots_per_allocation,
                              slot_node.size() - uint64_t{allocation} * slots_per_allocation);
  }

  // Where the brick for `slot` is read to: the slot itself (kMapped; the allocation is mapped on
  // first use) or the next staging brick (kStaged; waits for the ring's writes when it is full).
  Result<std::span<std::byte>> Destination(uint32_t slot) {
    if (mapped_path) {
      const uint32_t a = slot / slots_per_allocation;
      if (mapped[a] == nullptr) {
        cl_int err = CL_SUCCESS;
        void* ptr = clEnqueueMapBuffer(cc->queue(), bricks[a].get(), CL_TRUE, CL_MAP_WRITE, 0,
                                       SlotsIn(a) * device_brick_bytes, 0, nullptr, nullptr, &err);
        OCTO_RETURN_IF_ERROR(ClCheck(err, "clEnqueueMapBuffer(brick allocation)"));
        mapped[a] = static_cast<std::byte*>(ptr);
      }
      return std::span(mapped[a] + uint64_t{slot % slots_per_allocation} * device_brick_bytes,
                       device_brick_bytes);
    }
    if (staging_next == staging_bricks) {
      // The ring is full: its writes must have read it before it is refilled.
      OCTO_RETURN_IF_ERROR(cc->Finish());
      staging_next = 0;
    }
    return std::span(staging_ptr + staging_next * device_brick_bytes, device_brick_bytes);
  }

  // The brick at Destination(slot) is complete: kStaged sends it (non-blocking).
  Status Commit(uint32_t slot) {
    if (mapped_path) return Status::Ok();
    const std::byte* src = staging_ptr + staging_next * device_brick_bytes;
    ++staging_next;
    const uint64_t offset = uint64_t{slot % slots_per_allocation} * device_brick_bytes;
    return OCTO_CL(clEnqueueWriteBuffer(cc->queue(), bricks[slot / slots_per_allocation].get(),
                                        CL_FALSE, offset, device_brick_bytes, src, 0, nullptr,
                                        nullptr));
  }

  // Ends an Upload's transfers: unmaps the mapped allocations, waits for the staged writes.
  Status FinishTransfers() {
    Status first;
    for (std::byte*& ptr : mapped) {
      if (ptr == nullptr) continue;
      const size_t a = static_cast<size_t>(&ptr - mapped.data());
      Status unmapped =
          OCTO_CL(clEnqueueUnmapMemObject(cc->queue(), bricks[a].get(), ptr, 0, nullptr, nullptr));
      if (first.ok()) first = std::move(unmapped);
      ptr = nullptr;
    }
    if (staging_next > 0) {
      Status finished = cc->Finish();
      if (first.ok()) first = std::move(finished);
      staging_next = 0;
    }
    return first;
  }

  // Reads node `id`'s brick into `out` (device layout: uint16 samples), from RAM only when
  // resident_only. Writes nothing to `out` on failure.
  Status ReadInto(uint32_t id, std::span<std::byte> out, uint64_t* page) {
    if (bytes_per_sample == 2) {
      return resident_only ? tree->TryReadBrick(id, out, page) : tree->ReadBrick(id, out);
    }
    OCTO_RETURN_IF_ERROR(resident_only ? tree->TryReadBrick(id, raw, page)
                                       : tree->ReadBrick(id, raw));
    // uint8 trees: widened while copying into the destination.
    uint16_t* dst = reinterpret_cast<uint16_t*>(out.data());
    for (size_t i = 0; i < raw.size(); ++i) dst[i] = static_cast<uint16_t>(raw[i]);
    return Status::Ok();
  }

  // Cell ranges of the brick `bytes` (device layout) destined for `slot`, into the mirror.
  void ComputeCells(uint32_t slot, std::span<const std::byte> bytes) {
    const std::span<const uint16_t> samples(reinterpret_cast<const uint16_t*>(bytes.data()),
                                            bytes.size() / 2);
    ComputeCellRanges(tree->geometry(), samples,
                      std::span(cell_mirror).subspan(slot * cell_words, cell_words), &cell_scratch);
    if (cells_dirty_lo == cells_dirty_hi) {
      cells_dirty_lo = slot;
      cells_dirty_hi = slot + 1;
    } else {
      cells_dirty_lo = std::min(cells_dirty_lo, slot);
      cells_dirty_hi = std::max(cells_dirty_hi, slot + 1);
    }
  }

  // Writes the slots whose cell ranges changed (one blocking write of their span).
  Status WriteCells() {
    if (cells_dirty_lo == cells_dirty_hi) return Status::Ok();
    const uint64_t first = cells_dirty_lo * cell_words;
    const uint64_t count = (cells_dirty_hi - cells_dirty_lo) * cell_words;
    cells_dirty_lo = cells_dirty_hi = 0;
    return OCTO_CL(clEnqueueWriteBuffer(cc->queue(), cell_ranges_buffer.get(), CL_TRUE, first * 4,
                                        count * 4, cell_mirror.data() + first, 0, nullptr,
                                        nullptr));
  }

  Status Fill(const ClMem& buffer, size_t bytes) const {
    const cl_uint zero = 0;
    OCTO_CL_RETURN_IF_ERROR(clEnqueueFillBuffer(cc->queue(), buffer.get(), &zero, sizeof(zero), 0,
                                                bytes, 0, nullptr, nullptr));
    return cc->Finish();
  }
};

Result<std::unique_ptr<DeviceOctree>> DeviceOctree::Create(const ComputeContext* context,
                                                           octree::Octree* octree,
                                                           const DeviceOctreeOptions& options) {
  if (context == nullptr || octree == nullptr) {
    return InvalidArgumentError("DeviceOctree: null context or octree");
  }
  if (options.request_capacity == 0) {
    return InvalidArgumentError("DeviceOctree: request_capacity must be > 0");
  }
  if (options.change_backlog == 0) {
    return InvalidArgumentError("DeviceOctree: change_backlog must be > 0");
  }
  const octree::BrickGeometry& geometry = octree->geometry();
  std::unique_ptr<DeviceOctree> self(new DeviceOctree());
  self->octree_ = octree;
  self->impl_ = std::make_unique<Impl>();
  Impl& m = *self->impl_;
  m.cc = context;
  m.tree = octree;
  m.channels = geometry.channels();
  m.words = static_cast<size_t>(octree::NodeWords(m.channels));
  m.bytes_per_sample = geometry.bytes_per_sample();
  m.device_brick_bytes = geometry.brick_samples() * 2;
  m.cell_words = CellRangeWords(geometry);

  self->request_capacity_ = options.request_capacity;
  self->max_allocation_bytes_ = options.max_allocation_bytes;
  m.request_capacity = options.request_capacity;
  m.resident_only = options.brick_reads == BrickReads::kResidentOnly;
  m.transfer_fault = options.transfer_fault;
  m.mapped_path =
      options.upload_path == UploadPath::kMapped ||
      (options.upload_path == UploadPath::kAuto && context->device().type == DeviceType::kCpu);
  if (!m.mapped_path) {
    // The pinned staging ring, mapped once for the mirror's life.
    m.staging_bricks = std::max<uint64_t>(2, options.staging_bytes / m.device_brick_bytes);
    const uint64_t bytes = m.staging_bricks * m.device_brick_bytes;
    OCTO_ASSIGN_OR_RETURN(m.staging,
                          context->CreateBuffer(CL_MEM_READ_WRITE | CL_MEM_ALLOC_HOST_PTR, bytes));
    cl_int err = CL_SUCCESS;
    void* ptr =
        clEnqueueMapBuffer(context->queue(), m.staging.get(), CL_TRUE,
                           CL_MAP_WRITE_INVALIDATE_REGION, 0, bytes, 0, nullptr, nullptr, &err);
    OCTO_RETURN_IF_ERROR(ClCheck(err, "clEnqueueMapBuffer(staging)"));
    m.staging_ptr = static_cast<std::byte*>(ptr);
  }
  OCTO_RETURN_IF_ERROR(
      self->AllocateBricks(options.brick_buffer_bytes, options.max_allocation_bytes));
  if (m.bytes_per_sample == 1) m.raw.resize(geometry.brick_bytes());

  // Feedback buffers, zeroed (request_flags is created with the node buffer).
  OCTO_ASSIGN_OR_RETURN(
      m.request_list,
      context->CreateBuffer(CL_MEM_READ_WRITE, (size_t{m.request_capacity} + 1) * 4));
  OCTO_RETURN_IF_ERROR(m.Fill(m.request_list, (size_t{m.request_capacity} + 1) * 4));

  // Subscribe first, then walk: every change the walk may miss is delivered by the subscription
  // (a change it already saw may be replayed, which is harmless).
  m.changes = octree->SubscribeChanges(options.change_backlog);
  m.WalkTree();
  m.TakeWalk();
  m.EnsureCapacity(0);
  m.EncodePending();
  OCTO_RETURN_IF_ERROR(m.Flush(nullptr));
  return self;
}

DeviceOctree::~DeviceOctree() = default;

uint64_t DeviceOctree::MaxBrickBufferBytes(const octree::BrickGeometry& geometry) {
  return SlotsFor(geometry, std::numeric_limits<uint64_t>::max()) * DeviceBrickBytes(geometry);
}

Status DeviceOctree::AllocateBricks(uint64_t brick_buffer_bytes, uint64_t max_allocation_bytes) {
  Impl& m = *impl_;
  const uint64_t slot_count = SlotsFor(geometry(), brick_buffer_bytes);
  const uint64_t cap =
      max_allocation_bytes != 0 ? max_allocation_bytes : m.cc->device().max_alloc_bytes;
  const uint64_t per_allocation = std::min<uint64_t>(cap / m.device_brick_bytes, slot_count);
  if (per_allocation == 0) {
    return ResourceExhaustedError("DeviceOctree: one brick of " +
                                  std::to_string(m.device_brick_bytes) +
                                  " bytes exceeds the allocation cap of " + std::to_string(cap));
  }
  const uint64_t allocations = (slot_count + per_allocation - 1) / per_allocation;
  if (allocations > static_cast<uint64_t>(kMaxBrickAllocations)) {
    return ResourceExhaustedError("DeviceOctree: " + std::to_string(slot_count) +
                                  " brick slots of " + std::to_string(m.device_brick_bytes) +
                                  " bytes need " + std::to_string(allocations) +
                                  " allocations of at most " + std::to_string(cap) +
                                  " bytes; the limit is " + std::to_string(kMaxBrickAllocations));
  }
  std::vector<ClMem> bricks;
  for (uint64_t a = 0; a < allocations; ++a) {
    const uint64_t slots = std::min(per_allocation, slot_count - a * per_allocation);
    // Mapped uploads: memory the host can map without a copy.
    const cl_mem_flags flags =
        CL_MEM_READ_ONLY | (m.mapped_path ? CL_MEM_ALLOC_HOST_PTR : cl_mem_flags{0});
    OCTO_ASSIGN_OR_RETURN(ClMem buffer, m.cc->CreateBuffer(flags, slots * m.device_brick_bytes));
    bricks.push_back(std::move(buffer));
  }
  OCTO_ASSIGN_OR_RETURN(ClMem used, m.cc->CreateBuffer(CL_MEM_READ_WRITE, slot_count * 4));
  OCTO_RETURN_IF_ERROR(m.Fill(used, slot_count * 4));
  const uint64_t cell_bytes = slot_count * m.cell_words * 4;
  OCTO_ASSIGN_OR_RETURN(ClMem cells, m.cc->CreateBuffer(CL_MEM_READ_ONLY, cell_bytes));
  OCTO_RETURN_IF_ERROR(m.Fill(cells, cell_bytes));
  m.cell_ranges_buffer = std::move(cells);
  m.cell_mirror.assign(slot_count * m.cell_words, 0);
  m.cells_dirty_lo = 0;
  m.cells_dirty_hi = 0;
  m.bricks = std::move(bricks);
  m.mapped.assign(m.bricks.size(), nullptr);
  m.slot_used_buffer = std::move(used);
  m.slots_per_allocation = static_cast<uint32_t>(per_allocation);
  m.slot_node.assign(slot_count, kNoNode);
  m.slot_key.assign(slot_count, octree::NodeKey{});
  m.slot_used.assign(slot_count, 0);
  m.slot_owner.assign(slot_count, 0);
  m.reserved.clear();
  m.free_slots.clear();
  for (uint64_t slot = slot_count; slot-- > 0;) m.free_slots.push_back(static_cast<uint32_t>(slot));
  slot_count_ = static_cast<uint32_t>(slot_count);
  slots_per_allocation_ = static_cast<uint32_t>(per_allocation);
  return Status::Ok();
}

Status DeviceOctree::ResizeBrickBuffer(uint64_t brick_buffer_bytes) {
  Impl& m = *impl_;
  if (!m.bricks.empty() && SlotsFor(geometry(), brick_buffer_bytes) == slot_count_) {
    return Status::Ok();
  }
  // Every brick leaves (entries rewritten at the Flush below); then the old buffers go before the
  // new ones are allocated.
  for (uint32_t slot = 0; slot < slot_count_; ++slot) m.ReleaseSlot(slot, false);
  m.stale.clear();
  m.bricks.clear();
  m.mapped.clear();
  m.slot_used_buffer.reset();
  m.cell_ranges_buffer.reset();
  m.cell_mirror.clear();
  m.slot_node.clear();
  m.slot_key.clear();
  m.slot_used.clear();
  m.slot_owner.clear();
  m.reserved.clear();
  m.free_slots.clear();
  slot_count_ = 0;
  const Status allocated = AllocateBricks(brick_buffer_bytes, max_allocation_bytes_);
  const Status flushed = m.Flush(nullptr);
  OCTO_RETURN_IF_ERROR(allocated);
  return flushed;
}

void DeviceOctree::ReleaseReservations(uint64_t owner) {
  Impl& m = *impl_;
  if (owner == 0 || m.reserved.count(owner) == 0) return;
  for (uint64_t& slot_owner : m.slot_owner) {
    if (slot_owner == owner) slot_owner = 0;
  }
  m.reserved.erase(owner);
}

std::vector<uint64_t> DeviceOctree::TakeMissingPages() {
  Impl& m = *impl_;
  m.missing_seen.clear();
  return std::exchange(m.missing_pages, {});
}

Status DeviceOctree::Sync(SyncStats* stats) {
  Impl& m = *impl_;
  octree::ChangeBatch batch = m.changes.Poll();
  if (batch.resync) m.Resynchronise();
  const std::vector<octree::NodeChange>& changes = batch.events;
  // Apply liveness in event order (a delete and a re-creation of one id in one window both
  // count); node contents are read now, at least as new as the events.
  for (const octree::NodeChange& change : changes) {
    const uint32_t id = change.node;
    if (change.kind == octree::NodeChangeKind::kDeleted) {
      m.NodeGone(id);
      continue;
    }
    std::optional<octree::NodeSnapshot> snap = octree_->GetNode(id);
    if (!snap.has_value()) {
      m.NodeGone(id);
      continue;
    }
    m.EnsureCapacity(id);
    if (change.kind == octree::NodeChangeKind::kUpdated) {
      // The brick's bytes may have changed: re-upload it first, keep showing the old bytes.
      if (const auto it = m.slot_of.find(id);
          it != m.slot_of.end() && snap->has_brick() && m.slot_key[it->second] == snap->key) {
        m.stale.insert(id);
      }
    }
    m.live[id] = 1;
    m.key_of[id] = snap->key;
    m.to_encode.insert(id);
    m.snapshots.insert_or_assign(id, std::move(*snap));
  }
  m.EncodePending();
  uint64_t written = 0;
  OCTO_RETURN_IF_ERROR(m.Flush(&written));
  if (stats != nullptr) {
    stats->changes = changes.size();
    stats->resynchronised = batch.resync;
    stats->entries_written = written;
    stats->stale_bricks = m.stale.size();
  }
  return Status::Ok();
}

Result<uint32_t> DeviceOctree::BeginFrame() {
  Impl& m = *impl_;
  if (m.frame == std::numeric_limits<uint32_t>::max()) {
    // Wrap-around: old stamps would look newer than the restarted ones; clear them all.
    OCTO_RETURN_IF_ERROR(m.Fill(m.request_flags, m.capacity_nodes() * 4));
    OCTO_RETURN_IF_ERROR(m.Fill(m.slot_used_buffer, size_t{slot_count_} * 4));
    std::fill(m.slot_used.begin(), m.slot_used.end(), 0u);
    m.frame = 0;
  }
  ++m.frame;
  const cl_uint zero = 0;
  OCTO_RETURN_IF_ERROR(m.cc->WriteBuffer(m.request_list, 0, sizeof(zero), &zero));
  return m.frame;
}

Result<std::vector<uint32_t>> DeviceOctree::ReadFeedback() {
  Impl& m = *impl_;
  cl_uint count = 0;
  OCTO_RETURN_IF_ERROR(m.cc->ReadBuffer(m.request_list, 0, sizeof(count), &count));
  std::vector<uint32_t> ids(std::min<uint32_t>(count, m.request_capacity));
  if (!ids.empty()) {
    OCTO_RETURN_IF_ERROR(m.cc->ReadBuffer(m.request_list, 4, ids.size() * 4, ids.data()));
  }
  std::vector<uint32_t> used(slot_count_);
  OCTO_RETURN_IF_ERROR(m.cc->ReadBuffer(m.slot_used_buffer, 0, used.size() * 4, used.data()));
  // The host stamp of a fresh upload (its frame) wins over the previous occupant's stamp.
  for (size_t s = 0; s < used.size(); ++s) m.slot_used[s] = std::max(m.slot_used[s], used[s]);
  return ids;
}

Status DeviceOctree::Upload(std::span<const uint32_t> requested, const UploadBudget& budget,
                            UploadStats* stats) {
  Impl& m = *impl_;
  const auto start = std::chrono::steady_clock::now();
  const auto elapsed_ms = [&start] {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
        .count();
  };
  const int root_level = geometry().root_level();
  UploadStats s;

  // An id can be uploaded when it is live in the mirror with has_brick, owns a brick in the
  // tree now and is not resident.
  struct Item {
    uint32_t id;
    int level;
    octree::NodeKey key;
    bool stale;
    bool ancestor = false;  // Added as part of a requested node's chain, not requested itself.
  };
  const auto uploadable = [&m](const octree::NodeSnapshot& snap) {
    return snap.id < m.capacity_nodes() && m.live[snap.id] != 0 && snap.has_brick() &&
           octree::Word0HasBrick(m.Entry(snap.id)[0]) && m.slot_of.count(snap.id) == 0;
  };
  std::vector<Item> items;
  std::unordered_set<uint32_t> added;
  std::unordered_set<uint32_t> walked;
  for (uint32_t id : requested) {
    if (walked.count(id) != 0 || added.count(id) != 0) continue;
    std::optional<octree::NodeSnapshot> snap = octree_->GetNode(id);
    if (!snap.has_value() || !uploadable(*snap)) continue;
    added.insert(id);
    items.push_back(Item{id, snap->key.level, snap->key, false});
    walked.insert(id);
    // The chain: ancestors owning a brick that is not resident (coarse data shows first).
    octree::NodeKey key = snap->key;
    while (key.level < root_level) {
      key = octree::ParentKey(key);
      std::optional<octree::NodeSnapshot> parent = octree_->GetNode(key);
      if (!parent.has_value() || !walked.insert(parent->id).second) break;
      if (uploadable(*parent) && added.insert(parent->id).second) {
        items.push_back(Item{parent->id, parent->key.level, parent->key, false, true});
      }
    }
  }
  // The owner's previous reservation ends here (its pass has sampled those bricks); its new one
  // is capped so that the other owners and full frames keep room.
  ReleaseReservations(budget.reserve_for);
  const uint64_t reserve_cap = budget.reserve_for != 0 ? slot_count_ / (m.reserved.size() + 2) : 0;
  // Eviction candidates, computed once: occupied, unreserved slots older than protect_frame,
  // least recently used first, at equal stamps finer levels first.
  std::vector<uint32_t> victims;
  for (uint32_t slot = 0; slot < slot_count_; ++slot) {
    if (m.slot_node[slot] != kNoNode && m.slot_used[slot] < budget.protect_frame &&
        m.slot_owner[slot] == 0) {
      victims.push_back(slot);
    }
  }
  std::sort(victims.begin(), victims.end(), [&m](uint32_t a, uint32_t b) {
    return std::tie(m.slot_used[a], m.slot_key[a].level, a) <
           std::tie(m.slot_used[b], m.slot_key[b].level, b);
  });
  // When the chains do not fit the slots that can be filled (free or evictable), requested nodes
  // come before their ancestors: otherwise a ray front needing more bricks than the buffer has
  // would fill it with ancestors pass after pass and never get a requested brick (no progress).
  // The coarsest ancestors keep whatever room is left.
  const uint64_t room = m.free_slots.size() + victims.size();
  s.requested = items.size();
  if (items.size() > room) {
    std::vector<Item> ancestors;
    std::vector<Item> wanted;
    for (const Item& item : items) (item.ancestor ? ancestors : wanted).push_back(item);
    std::sort(ancestors.begin(), ancestors.end(), [](const Item& a, const Item& b) {
      return std::tie(b.level, a.id) < std::tie(a.level, b.id);
    });
    const size_t keep = room > wanted.size() ? static_cast<size_t>(room - wanted.size()) : 0;
    if (ancestors.size() > keep) {
      s.deferred += ancestors.size() - keep;
      ancestors.resize(keep);
    }
    items = std::move(wanted);
    items.insert(items.end(), ancestors.begin(), ancestors.end());
  }
  // Coarse first (higher level), then by id.
  std::sort(items.begin(), items.end(), [](const Item& a, const Item& b) {
    return std::tie(b.level, a.id) < std::tie(a.level, b.id);
  });
  // Stale resident bricks go first.
  std::vector<Item> order;
  order.reserve(m.stale.size() + items.size());
  for (uint32_t id : m.stale) {
    const uint32_t slot = m.slot_of.at(id);
    order.push_back(Item{id, m.slot_key[slot].level, m.slot_key[slot], true});
  }
  order.insert(order.end(), items.begin(), items.end());

  size_t next_victim = 0;
  std::vector<uint8_t> filled_now(slot_count_, 0);

  Status status;
  uint64_t done = 0;
  for (size_t i = 0; i < order.size(); ++i) {
    const bool over_count = budget.max_bricks != 0 && done >= budget.max_bricks;
    if (done >= 1 && (over_count || elapsed_ms() >= budget.max_ms)) {
      s.deferred += order.size() - i;
      break;
    }
    const Item& item = order[i];
    const auto resident = m.slot_of.find(item.id);
    if (item.stale && resident == m.slot_of.end()) continue;
    if (!item.stale && resident != m.slot_of.end()) continue;
    // The slot first (nothing changes yet): the resident one, a free one, else the next victim.
    uint32_t slot;
    bool evict = false;
    if (item.stale) {
      slot = resident->second;
    } else if (!m.free_slots.empty()) {
      slot = m.free_slots.back();
    } else {
      while (next_victim < victims.size() && (filled_now[victims[next_victim]] != 0 ||
                                              m.slot_node[victims[next_victim]] == kNoNode)) {
        ++next_victim;
      }
      if (next_victim == victims.size()) {
        // Every slot is protected or was filled by this call: the rest waits.
        s.deferred += order.size() - i;
        break;
      }
      slot = victims[next_victim];
      evict = true;
    }
    Result<std::span<std::byte>> destination = m.Destination(slot);
    if (!destination.ok()) {
      status = destination.status();
      break;
    }
    // Read straight into the destination; a failed read writes nothing, so a node that lost
    // its brick meanwhile costs no eviction.
    uint64_t page = 0;
    const Status read = m.ReadInto(item.id, *destination, &page);
    if (read.code() == StatusCode::kUnavailable) {
      // Its page is not in RAM: the next frame asks again; the caller prefetches the page.
      ++s.unavailable;
      if (m.missing_seen.insert(page).second) m.missing_pages.push_back(page);
      continue;
    }
    if (read.code() == StatusCode::kNotFound) {
      // Gone or brickless: its change event follows; drop the stale copy now.
      if (item.stale) m.ReleaseSlot(resident->second, true);
      continue;
    }
    if (!read.ok()) {
      status = read;
      break;
    }
    // The cell ranges of exactly the bytes the device receives.
    m.ComputeCells(slot, *destination);
    if (evict) {
      ++next_victim;
      m.ReleaseSlot(slot, false);
      ++s.evicted;
    } else if (!item.stale) {
      m.free_slots.pop_back();
    }
    if (Status write = m.Commit(slot); !write.ok()) {
      if (!item.stale) m.free_slots.push_back(slot);
      status = write;
      break;
    }
    filled_now[slot] = 1;
    ++done;
    ++s.uploaded;
    s.bytes += m.device_brick_bytes;
    if (item.stale) {
      ++s.reuploaded;
      m.stale.erase(item.id);
      continue;
    }
    m.slot_node[slot] = item.id;
    m.slot_key[slot] = item.key;
    m.slot_used[slot] = m.frame;
    m.slot_of[item.id] = slot;
    m.WriteResidency(item.id);
    if (!item.ancestor && s.reserved < reserve_cap) {
      m.slot_owner[slot] = budget.reserve_for;
      ++m.reserved[budget.reserve_for];
      ++s.reserved;
    }
  }
  // The bytes and their cell ranges are on the device (unmapped / written) before the entries
  // say so; when either transfer failed, none of this call's bricks can be trusted.
  Status finished = m.FinishTransfers();
  if (finished.ok() && m.transfer_fault) finished = m.transfer_fault("bricks");
  Status cells = m.transfer_fault ? m.transfer_fault("cells") : Status::Ok();
  if (cells.ok()) cells = m.WriteCells();
  if (!finished.ok() || !cells.ok()) {
    for (uint32_t slot = 0; slot < slot_count_; ++slot) {
      if (filled_now[slot] != 0) m.ReleaseSlot(slot, true);
    }
    s.uploaded = s.reuploaded = s.reserved = s.bytes = 0;
  }
  if (status.ok()) status = !finished.ok() ? std::move(finished) : std::move(cells);
  // The residency bits reach the device even when an upload failed midway.
  const Status flushed = m.Flush(nullptr);
  total_uploaded_ += s.uploaded;
  s.ms = elapsed_ms();
  if (stats != nullptr) *stats = s;
  OCTO_RETURN_IF_ERROR(status);
  return flushed;
}

Status DeviceOctree::UploadAll(std::span<const uint32_t> nodes, uint32_t protect_frame,
                               UploadStats* stats) {
  UploadBudget budget;
  budget.max_ms = std::numeric_limits<double>::infinity();
  budget.max_bricks = 0;
  budget.protect_frame = protect_frame;
  return Upload(nodes, budget, stats);
}

Status DeviceOctree::UploadCoarseLevels(uint64_t max_bytes, UploadStats* stats) {
  const uint64_t max_bricks =
      std::min<uint64_t>(max_bytes / impl_->device_brick_bytes, slot_count_ / 4);
  std::vector<uint32_t> chosen;
  std::vector<uint32_t> level = {0};  // The root.
  // Level by level: a level's brick-owning nodes join only when all of them fit.
  while (!level.empty()) {
    std::vector<uint32_t> bricks, next;
    for (const uint32_t id : level) {
      const std::optional<octree::NodeSnapshot> node = octree_->GetNode(id);
      if (!node.has_value()) continue;  // Deleted meanwhile (construction goes on).
      if (node->has_brick()) bricks.push_back(id);
      if (node->has_children()) {
        for (uint32_t octant = 0; octant < 8; ++octant)
          next.push_back(8 * node->child_group + octant);
      }
    }
    if (chosen.size() + bricks.size() > max_bricks) break;
    chosen.insert(chosen.end(), bricks.begin(), bricks.end());
    level = std::move(next);
  }
  if (stats != nullptr) *stats = {};
  if (chosen.empty()) return Status::Ok();
  return UploadAll(chosen, /*protect_frame=*/0, stats);  // 0: no slot is evictable.
}

cl_mem DeviceOctree::node_buffer() const { return impl_->node_buffer.get(); }

std::array<cl_mem, kMaxBrickAllocations> DeviceOctree::brick_buffers() const {
  std::array<cl_mem, kMaxBrickAllocations> out{};
  if (impl_->bricks.empty()) return out;  // A failed resize: no kernel may run on this mirror.
  for (int a = 0; a < kMaxBrickAllocations; ++a) {
    out[a] = impl_->bricks[static_cast<size_t>(a) < impl_->bricks.size() ? a : 0].get();
  }
  return out;
}

cl_mem DeviceOctree::request_flags() const { return impl_->request_flags.get(); }
cl_mem DeviceOctree::request_list() const { return impl_->request_list.get(); }
cl_mem DeviceOctree::slot_used() const { return impl_->slot_used_buffer.get(); }
cl_mem DeviceOctree::cell_ranges() const { return impl_->cell_ranges_buffer.get(); }
uint64_t DeviceOctree::cell_range_words() const { return impl_->cell_words; }

int DeviceOctree::allocation_count() const { return static_cast<int>(impl_->bricks.size()); }
uint64_t DeviceOctree::resident_bricks() const { return impl_->slot_of.size(); }

uint64_t DeviceOctree::brick_buffer_bytes() const {
  return uint64_t{slot_count_} * impl_->device_brick_bytes;
}

uint64_t DeviceOctree::device_bytes() const {
  const Impl& m = *impl_;
  return brick_buffer_bytes() + m.mirror.size() * 4 + m.capacity_nodes() * 4 +
         (uint64_t{m.request_capacity} + 1) * 4 + uint64_t{slot_count_} * 4 +
         m.cell_mirror.size() * 4;
}

uint64_t DeviceOctree::reserved_slots() const {
  uint64_t total = 0;
  for (const auto& [owner, count] : impl_->reserved) total += count;
  return total;
}

std::optional<uint32_t> DeviceOctree::SlotOf(uint32_t id) const {
  const auto it = impl_->slot_of.find(id);
  if (it == impl_->slot_of.end()) return std::nullopt;
  return it->second;
}

std::span<const uint32_t> DeviceOctree::node_mirror() const { return impl_->mirror; }

uint64_t DeviceOctree::node_capacity() const { return impl_->capacity_nodes(); }
uint32_t DeviceOctree::frame() const { return impl_->frame; }
uint64_t DeviceOctree::device_brick_bytes() const { return impl_->device_brick_bytes; }
std::span<const uint32_t> DeviceOctree::slot_stamps() const { return impl_->slot_used; }

UploadPath DeviceOctree::upload_path() const {
  return impl_->mapped_path ? UploadPath::kMapped : UploadPath::kStaged;
}

}  // namespace octoscope::render
