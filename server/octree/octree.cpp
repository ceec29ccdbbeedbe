#include "octree/octree.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <utility>

#include "octree/node_encoding.h"
#include "util/checked_math.h"

namespace octoscope::octree {
namespace {

inline uint16_t LoadSample(const std::byte* p, int bps) {
  if (bps == 1) return static_cast<uint16_t>(std::to_integer<uint8_t>(*p));
  uint16_t v;
  std::memcpy(&v, p, 2);
  return v;
}

inline void StoreSample(std::byte* p, int bps, uint16_t v) {
  if (bps == 1) {
    *p = static_cast<std::byte>(v);
  } else {
    std::memcpy(p, &v, 2);
  }
}

// Index of voxel p in a buffer laid out over `box`, x fastest.
inline size_t BufferIndex(const Box& box, int64_t x, int64_t y, int64_t z) {
  return static_cast<size_t>(((z - box.lo[2]) * box.Extent(1) + (y - box.lo[1])) * box.Extent(0) +
                             (x - box.lo[0]));
}

template <typename F>
void ForEachIndex(const Box& b, F&& f) {
  for (int64_t z = b.lo[2]; z < b.hi[2]; ++z)
    for (int64_t y = b.lo[1]; y < b.hi[1]; ++y)
      for (int64_t x = b.lo[0]; x < b.hi[0]; ++x) f(Vec3{x, y, z});
}

}  // namespace

// --------------------------------------------------------------------------------------------
// Construction.

Octree::Octree(const BrickGeometry& geometry, paging::PageCache* cache, uint32_t bricks_per_page)
    : geometry_(geometry),
      channels_(geometry.channels()),
      cache_(cache),
      pool_(cache, geometry.brick_bytes(), bricks_per_page) {}

Octree::~Octree() = default;

Result<std::unique_ptr<Octree>> Octree::Create(const BrickGeometry& geometry,
                                               const OctreeOptions& options,
                                               paging::PageCache* cache) {
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<Octree> tree, CreateImpl(geometry, options, cache));
  // The root: group 0, id 0, storing the background.
  tree->nodes_.assign(8, NodeRecord{});
  tree->stats_.assign(8 * static_cast<size_t>(tree->channels_), ChannelStats{});
  tree->group_parent_.assign(1, 0);
  tree->nodes_[0].level = static_cast<uint8_t>(geometry.root_level());
  tree->nodes_[0].flags = kLive;
  for (int c = 0; c < tree->channels_; ++c) {
    const uint16_t bg = tree->background_[c];
    tree->Stat(0, c) = ChannelStats{bg, bg, bg, bg, static_cast<double>(bg)};
  }
  tree->changes_.Append(0, NodeChangeKind::kCreated);
  return tree;
}

Result<std::unique_ptr<Octree>> Octree::Create(const volume::VolumeInfo& info,
                                               const OctreeOptions& options,
                                               paging::PageCache* cache) {
  OCTO_RETURN_IF_ERROR(info.Validate());
  BrickGeometry::Params params;
  params.volume_size = info.size;
  params.brick_size = options.brick_size;
  params.channels = info.channel_count();
  params.bytes_per_sample = options.bytes_per_sample;
  if (params.bytes_per_sample == 0) {
    params.bytes_per_sample = volume::BytesPerSample(info.dtype) == 1 ? 1 : 2;
  }
  OCTO_ASSIGN_OR_RETURN(BrickGeometry geometry, BrickGeometry::Create(params));
  return Create(geometry, options, cache);
}

Result<std::unique_ptr<Octree>> Octree::CreateImpl(const BrickGeometry& geometry,
                                                   const OctreeOptions& options,
                                                   paging::PageCache* cache) {
  if (cache == nullptr) return InvalidArgumentError("octree: no page cache");
  const int channels = geometry.channels();
  const uint64_t brick_bytes = geometry.brick_bytes();
  if (cache->page_bytes() < brick_bytes) {
    return InvalidArgumentError("octree: a page of " + std::to_string(cache->page_bytes()) +
                                " bytes cannot hold one brick of " + std::to_string(brick_bytes) +
                                " bytes (" + geometry.ToString() + ")");
  }
  const uint64_t per_page =
      std::min<uint64_t>(cache->page_bytes() / brick_bytes, std::numeric_limits<uint32_t>::max());
  if (!(options.homogeneity_threshold >= 0.0 && options.homogeneity_threshold <= 1.0)) {
    return InvalidArgumentError("octree: homogeneity threshold " +
                                std::to_string(options.homogeneity_threshold) +
                                " is outside [0, 1]");
  }
  auto check_size = [&](size_t n, const char* what) -> Status {
    if (n != 0 && n != static_cast<size_t>(channels)) {
      return InvalidArgumentError(std::string("octree: ") + what + " has " + std::to_string(n) +
                                  " entries for " + std::to_string(channels) + " channels");
    }
    return Status::Ok();
  };
  OCTO_RETURN_IF_ERROR(check_size(options.value_range.size(), "value_range"));
  OCTO_RETURN_IF_ERROR(check_size(options.homogeneity_tolerance.size(), "homogeneity_tolerance"));
  OCTO_RETURN_IF_ERROR(check_size(options.background.size(), "background"));
  const uint32_t type_max = geometry.bytes_per_sample() == 1 ? 255u : 65535u;

  std::unique_ptr<Octree> tree(new Octree(geometry, cache, static_cast<uint32_t>(per_page)));
  tree->tolerance_.resize(channels);
  tree->background_.resize(channels);
  for (int c = 0; c < channels; ++c) {
    if (!options.homogeneity_tolerance.empty()) {
      tree->tolerance_[c] = options.homogeneity_tolerance[c];
    } else {
      const double range = options.value_range.empty() ? type_max : options.value_range[c];
      // A tiny epsilon so that e.g. 0.05 * 65535 is not floored one below its decimal value.
      tree->tolerance_[c] =
          static_cast<uint32_t>(std::floor(options.homogeneity_threshold * range + 1e-9));
    }
    const uint16_t bg = options.background.empty() ? 0 : options.background[c];
    if (bg > type_max) {
      return InvalidArgumentError("octree: background " + std::to_string(bg) +
                                  " does not fit the stored sample type");
    }
    tree->background_[c] = bg;
  }
  return tree;
}

// --------------------------------------------------------------------------------------------
// Node table queries.

Octree::Located Octree::Locate(const NodeKey& key) const {
  uint32_t id = 0;
  int level = geometry_.root_level();
  while (level > key.level) {
    const uint32_t group = nodes_[id].child_group;
    if (group == 0) break;
    const int shift = level - 1 - key.level;
    int octant = 0;
    for (int a = 0; a < 3; ++a) octant |= static_cast<int>((key.index[a] >> shift) & 1) << a;
    id = group * 8 + static_cast<uint32_t>(octant);
    --level;
  }
  return Located{id, level == key.level};
}

NodeKey Octree::KeyOf(uint32_t id) const {
  NodeKey key;
  key.level = nodes_[id].level;
  int shift = 0;
  uint32_t cur = id;
  while (cur != 0) {
    const uint32_t octant = cur % 8;
    for (int a = 0; a < 3; ++a) key.index[a] |= static_cast<int64_t>((octant >> a) & 1) << shift;
    ++shift;
    cur = group_parent_[cur / 8];
  }
  return key;
}

uint16_t Octree::Uniform(uint32_t id, int c) const {
  const double v = std::floor(Stat(id, c).avg + 0.5);
  const double type_max = geometry_.bytes_per_sample() == 1 ? 255.0 : 65535.0;
  return static_cast<uint16_t>(std::clamp(v, 0.0, type_max));
}

bool Octree::IsLiveId(uint32_t id) const {
  if (id >= nodes_.size() || (nodes_[id].flags & kLive) == 0) return false;
  return id == 0 || id >= 8;
}

NodeSnapshot Octree::SnapshotLocked(uint32_t id) const {
  const NodeRecord& r = nodes_[id];
  NodeSnapshot s;
  s.id = id;
  s.key = KeyOf(id);
  s.child_group = r.child_group;
  s.brick = r.brick;
  s.is_virtual = (r.flags & kVirtual) != 0;
  s.complete = (r.flags & kComplete) != 0;
  s.channels.resize(channels_);
  for (int c = 0; c < channels_; ++c) {
    const ChannelStats& st = Stat(id, c);
    s.channels[c] = ChannelSummary{st.min, st.max, st.sub_min, st.sub_max, st.avg};
  }
  return s;
}

std::optional<NodeSnapshot> Octree::GetNode(const NodeKey& key) const {
  if (!geometry_.IsValidKey(key)) return std::nullopt;
  std::shared_lock<std::shared_mutex> lock(mu_);
  const Located loc = Locate(key);
  if (!loc.exact) return std::nullopt;
  return SnapshotLocked(loc.id);
}

std::optional<NodeSnapshot> Octree::GetNode(uint32_t id) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  if (!IsLiveId(id)) return std::nullopt;
  return SnapshotLocked(id);
}

Status Octree::ReadBrick(uint32_t id, std::span<std::byte> out) const {
  if (out.size() != geometry_.brick_bytes()) {
    return InvalidArgumentError("octree: ReadBrick buffer of " + std::to_string(out.size()) +
                                " bytes, brick has " + std::to_string(geometry_.brick_bytes()));
  }
  // The shared lock keeps the brick from being dropped (that takes mu_ exclusively) while we
  // copy; the stripe lock keeps the inserting thread from modifying its bytes meanwhile.
  std::shared_lock<std::shared_mutex> lock(mu_);
  if (!IsLiveId(id)) return NotFoundError("octree: node " + std::to_string(id) + " does not exist");
  const uint32_t brick = nodes_[id].brick;
  if (brick == 0) return NotFoundError("octree: node " + std::to_string(id) + " has no brick");
  OCTO_ASSIGN_OR_RETURN(BrickHandle handle, pool_.Pin(brick));
  std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
  std::span<const std::byte> src = std::as_const(handle).data();
  std::memcpy(out.data(), src.data(), src.size());
  return Status::Ok();
}

OctreeStats Octree::stats() const {
  OctreeStats s;
  {
    std::shared_lock<std::shared_mutex> lock(mu_);
    for (uint32_t id = 0; id < nodes_.size(); ++id) {
      if (!IsLiveId(id)) continue;
      ++s.nodes;
      if ((nodes_[id].flags & kVirtual) == 0 && nodes_[id].brick == 0) ++s.homogeneous_nodes;
    }
  }
  s.bricks = pool_.live_bricks();
  s.pool_bytes = pool_.pool_bytes();
  return s;
}

Status Octree::Flush() { return cache_->Flush(); }

// --------------------------------------------------------------------------------------------
// Structure mutations. All run on the inserting thread (insert_mu_ held), read the table without
// a lock (no one else writes it) and take mu_ exclusively only to modify it, never while holding
// a page pin (a reader may hold mu_ shared while it waits in PageCache::Pin).

Status Octree::CreateChildren(uint32_t id) {
  const NodeKey key = KeyOf(id);
  std::unique_lock<std::shared_mutex> lock(mu_);
  uint32_t group;
  if (!free_groups_.empty()) {
    group = *free_groups_.begin();
    free_groups_.erase(free_groups_.begin());
  } else {
    if (group_parent_.size() > kMaxChildGroup) {
      return ResourceExhaustedError("octree: more than 2^30 child groups");
    }
    group = static_cast<uint32_t>(group_parent_.size());
    group_parent_.push_back(kFreeGroup);
    nodes_.resize(nodes_.size() + 8);
    stats_.resize(stats_.size() + 8 * static_cast<size_t>(channels_));
  }
  group_parent_[group] = id;
  const bool parent_complete = (nodes_[id].flags & kComplete) != 0;
  for (int octant = 0; octant < 8; ++octant) {
    const uint32_t child = group * 8 + static_cast<uint32_t>(octant);
    const bool is_virtual = geometry_.IsVirtual(ChildKey(key, octant));
    NodeRecord& r = nodes_[child];
    r = NodeRecord{};
    r.level = static_cast<uint8_t>(key.level - 1);
    r.flags = static_cast<uint8_t>(kLive | (is_virtual ? kVirtual : 0) |
                                   (is_virtual || parent_complete ? kComplete : 0));
    for (int c = 0; c < channels_; ++c) {
      // New children show what the parent showed for their region: its average (the background
      // for a fresh parent; the pruned average when re-opening a pruned node).
      if (is_virtual) {
        const uint16_t bg = background_[c];
        Stat(child, c) = ChannelStats{bg, bg, bg, bg, static_cast<double>(bg)};
      } else {
        const uint16_t u = Uniform(id, c);
        Stat(child, c) = ChannelStats{u, u, u, u, Stat(id, c).avg};
      }
    }
  }
  nodes_[id].child_group = group;
  lock.unlock();
  for (int octant = 0; octant < 8; ++octant) {
    changes_.Append(group * 8 + static_cast<uint32_t>(octant), NodeChangeKind::kCreated);
  }
  changes_.Append(id, NodeChangeKind::kUpdated);
  return Status::Ok();
}

Result<uint32_t> Octree::EnsureNode(const NodeKey& key) {
  for (;;) {
    const Located loc = Locate(key);
    if (loc.exact) return loc.id;
    // Locate stopped at a childless ancestor: give it its 8 children and descend further.
    OCTO_RETURN_IF_ERROR(CreateChildren(loc.id));
  }
}

Status Octree::AllocateBrick(uint32_t id, const NodeKey& key) {
  OCTO_ASSIGN_OR_RETURN(uint32_t brick, pool_.Allocate());
  // The new brick shows exactly what the node showed without it: its interior is the node's
  // uniform value, its apron the neighbours' current representation (the node itself is not yet
  // published, so ReadRepresentation returns its uniform value for the interior).
  const Box stored = geometry_.StoredBox(key);
  std::vector<uint16_t> values(stored.VoxelCount());
  {
    auto handle = pool_.Pin(brick);
    if (!handle.ok()) {
      pool_.Free(brick);
      return handle.status();
    }
    for (int c = 0; c < channels_; ++c) {
      Status st = ReadRepresentation(key.level, stored, c, values.data());
      if (!st.ok()) {
        handle->Reset();
        pool_.Free(brick);
        return st;
      }
      handle->MarkDirty();
      std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
      std::span<std::byte> data = handle->data();
      const int bps = geometry_.bytes_per_sample();
      const Vec3 s = geometry_.stored_size();
      size_t i = 0;
      for (int64_t z = 0; z < s[2]; ++z)
        for (int64_t y = 0; y < s[1]; ++y)
          for (int64_t x = 0; x < s[0]; ++x, ++i)
            StoreSample(data.data() + geometry_.LocalSampleOffset({x, y, z}, c) * bps, bps,
                        values[i]);
    }
  }
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    nodes_[id].brick = brick;
  }
  changes_.Append(id, NodeChangeKind::kUpdated);
  return Status::Ok();
}

Status Octree::DropBrick(uint32_t id, const NodeKey& key) {
  uint32_t brick;
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    brick = nodes_[id].brick;
    nodes_[id].brick = 0;
  }
  pool_.Free(brick);
  changes_.Append(id, NodeChangeKind::kUpdated);
  // Neighbours' aprons showed this node's voxels; now they must show its average.
  return RefreshAprons(key.level, geometry_.NodeBox(key));
}

Status Octree::DeleteChildren(uint32_t id, const NodeKey& key) {
  std::vector<uint32_t> groups;
  std::vector<uint32_t> stack{nodes_[id].child_group};
  while (!stack.empty()) {
    const uint32_t g = stack.back();
    stack.pop_back();
    groups.push_back(g);
    for (uint32_t n = g * 8; n < g * 8 + 8; ++n) {
      if (nodes_[n].child_group != 0) stack.push_back(nodes_[n].child_group);
    }
  }
  std::vector<uint32_t> bricks;
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    for (uint32_t g : groups) {
      for (uint32_t n = g * 8; n < g * 8 + 8; ++n) {
        if (nodes_[n].brick != 0) bricks.push_back(nodes_[n].brick);
        nodes_[n] = NodeRecord{};
        progress_.erase(n);
      }
      group_parent_[g] = kFreeGroup;
      free_groups_.insert(g);
    }
    nodes_[id].child_group = 0;
  }
  for (uint32_t b : bricks) pool_.Free(b);
  for (uint32_t g : groups) {
    for (uint32_t n = g * 8; n < g * 8 + 8; ++n) changes_.Append(n, NodeChangeKind::kDeleted);
  }
  changes_.Append(id, NodeChangeKind::kUpdated);
  // At every level below, the bricks around this node's region showed the deleted nodes'
  // averages; now the region is represented by this node's average.
  for (int level = key.level - 1; level >= 0; --level) {
    OCTO_RETURN_IF_ERROR(
        RefreshAprons(level, RefineBox(geometry_.NodeBox(key), key.level - level)));
  }
  return Status::Ok();
}

Status Octree::RefreshAprons(int level, const Box& region) {
  const Box valid_region = region.Intersect(geometry_.ValidExtent(level));
  if (valid_region.empty()) return Status::Ok();
  const Box storing =
      geometry_.NodesStoringAny(level, valid_region).Intersect(geometry_.NonVirtualNodes(level));
  const Box owning = geometry_.NodesIntersecting(level, valid_region);
  std::vector<uint16_t> values;
  for (int64_t z = storing.lo[2]; z < storing.hi[2]; ++z) {
    for (int64_t y = storing.lo[1]; y < storing.hi[1]; ++y) {
      const bool yz_inside =
          owning.lo[1] <= y && y < owning.hi[1] && owning.lo[2] <= z && z < owning.hi[2];
      for (int64_t x = storing.lo[0]; x < storing.hi[0]; ++x) {
        // Only the shell around the region: nodes inside it are the ones that changed.
        if (yz_inside && owning.lo[0] <= x && x < owning.hi[0]) {
          x = owning.hi[0] - 1;
          continue;
        }
        const NodeKey nk{level, {x, y, z}};
        const Located loc = Locate(nk);
        if (!loc.exact || nodes_[loc.id].brick == 0) continue;
        const Box part = geometry_.StoredBox(nk).Intersect(valid_region);
        if (part.empty()) continue;
        values.resize(part.VoxelCount());
        for (int c = 0; c < channels_; ++c) {
          OCTO_RETURN_IF_ERROR(ReadRepresentation(level, part, c, values.data()));
          OCTO_RETURN_IF_ERROR(PutRegion(nodes_[loc.id].brick, nk, part, c, values.data(), part));
        }
        changes_.Append(loc.id, NodeChangeKind::kUpdated);
      }
    }
  }
  return Status::Ok();
}

// --------------------------------------------------------------------------------------------
// Voxel access.

Status Octree::PutRegion(uint32_t brick, const NodeKey& key, const Box& region, int c,
                         const uint16_t* src, const Box& src_box) {
  OCTO_ASSIGN_OR_RETURN(BrickHandle handle, pool_.Pin(brick));
  handle.MarkDirty();
  std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
  std::byte* data = handle.data().data();
  const int bps = geometry_.bytes_per_sample();
  const size_t stride = static_cast<size_t>(channels_) * bps;
  for (int64_t z = region.lo[2]; z < region.hi[2]; ++z) {
    for (int64_t y = region.lo[1]; y < region.hi[1]; ++y) {
      std::byte* dst = data + geometry_.StoredByteOffset(key, {region.lo[0], y, z}, c);
      const uint16_t* s = src + BufferIndex(src_box, region.lo[0], y, z);
      for (int64_t x = 0; x < region.Extent(0); ++x) StoreSample(dst + x * stride, bps, s[x]);
    }
  }
  return Status::Ok();
}

Status Octree::ReadRepresentation(int level, const Box& box, int c, uint16_t* out) const {
  std::fill(out, out + box.VoxelCount(), background_[c]);  // Virtual voxels.
  const Box valid = box.Intersect(geometry_.ValidExtent(level));
  if (valid.empty()) return Status::Ok();
  const Box nodes =
      geometry_.NodesIntersecting(level, valid).Intersect(geometry_.NonVirtualNodes(level));
  const int bps = geometry_.bytes_per_sample();
  const size_t stride = static_cast<size_t>(channels_) * bps;
  Status status;
  ForEachIndex(nodes, [&](const Vec3& index) {
    if (!status.ok()) return;
    const NodeKey key{level, index};
    const Box region = geometry_.NodeBox(key).Intersect(valid);
    const Located loc = Locate(key);
    const uint32_t brick = loc.exact ? nodes_[loc.id].brick : 0;
    if (brick == 0) {
      const uint16_t u = Uniform(loc.id, c);
      ForEachIndex(Box{{region.lo[0], region.lo[1], region.lo[2]},
                       {region.lo[0] + 1, region.hi[1], region.hi[2]}},
                   [&](const Vec3& p) {
                     uint16_t* row = out + BufferIndex(box, p[0], p[1], p[2]);
                     std::fill(row, row + region.Extent(0), u);
                   });
      return;
    }
    auto handle = pool_.Pin(brick);
    if (!handle.ok()) {
      status = handle.status();
      return;
    }
    const std::byte* data = std::as_const(*handle).data().data();
    for (int64_t z = region.lo[2]; z < region.hi[2]; ++z) {
      for (int64_t y = region.lo[1]; y < region.hi[1]; ++y) {
        const std::byte* src = data + geometry_.StoredByteOffset(key, {region.lo[0], y, z}, c);
        uint16_t* dst = out + BufferIndex(box, region.lo[0], y, z);
        for (int64_t x = 0; x < region.Extent(0); ++x) dst[x] = LoadSample(src + x * stride, bps);
      }
    }
  });
  return status;
}

Status Octree::WriteLevel(int level, const Box& box, int c, const std::vector<uint16_t>& values,
                          std::vector<uint32_t>* touched) {
  const Box nodes =
      geometry_.NodesStoringAny(level, box).Intersect(geometry_.NonVirtualNodes(level));
  Status status;
  ForEachIndex(nodes, [&](const Vec3& index) {
    if (!status.ok()) return;
    const NodeKey key{level, index};
    const Box interior = geometry_.NodeBox(key).Intersect(box);
    uint32_t id;
    if (!interior.empty()) {
      auto ensured = EnsureNode(key);
      if (!ensured.ok()) {
        status = ensured.status();
        return;
      }
      id = *ensured;
      touched->push_back(id);
      if (level == 0) MarkLeafWritten(id, key, interior, c);
      if (nodes_[id].brick == 0) {
        // Without a brick the node shows its uniform value; only a different value needs one.
        const uint16_t u = Uniform(id, c);
        bool differs = false;
        ForEachIndex(interior, [&](const Vec3& p) {
          differs = differs || values[BufferIndex(box, p[0], p[1], p[2])] != u;
        });
        if (!differs) return;
        status = AllocateBrick(id, key);
        if (!status.ok()) return;
      }
    } else {
      // Only the apron of this node overlaps: update it if the node exists with a brick.
      const Located loc = Locate(key);
      if (!loc.exact || nodes_[loc.id].brick == 0) return;
      id = loc.id;
    }
    const Box part = geometry_.StoredBox(key).Intersect(box);
    status = PutRegion(nodes_[id].brick, key, part, c, values.data(), box);
    changes_.Append(id, NodeChangeKind::kUpdated);
  });
  return status;
}

void Octree::MarkLeafWritten(uint32_t id, const NodeKey& key, const Box& box, int c) {
  if ((nodes_[id].flags & kComplete) != 0) return;
  LeafProgress& progress = progress_[id];
  if ((progress.complete_channels >> c) & 1) return;
  if (progress.channels.empty()) progress.channels.resize(channels_);
  const Box valid = geometry_.ValidBox(key);
  std::unique_ptr<WriteCoverage>& coverage = progress.channels[c];
  if (!coverage) {
    coverage =
        std::make_unique<WriteCoverage>(Vec3{valid.Extent(0), valid.Extent(1), valid.Extent(2)});
  }
  const Box b = box.Intersect(valid);
  coverage->Mark(Box{{b.lo[0] - valid.lo[0], b.lo[1] - valid.lo[1], b.lo[2] - valid.lo[2]},
                     {b.hi[0] - valid.lo[0], b.hi[1] - valid.lo[1], b.hi[2] - valid.lo[2]}});
  if (!coverage->complete()) return;
  coverage.reset();
  progress.complete_channels |= uint64_t{1} << c;
  const uint64_t all = channels_ == 64 ? ~uint64_t{0} : (uint64_t{1} << channels_) - 1;
  if (progress.complete_channels == all) {
    progress_.erase(id);
    std::unique_lock<std::shared_mutex> lock(mu_);
    nodes_[id].flags |= kComplete;
  }
}

// Step 3 for one node: statistics of channel c, completeness, pruning.
Status Octree::UpdateNode(uint32_t id, int c) {
  if ((nodes_[id].flags & kLive) == 0) return Status::Ok();  // Deleted by an ancestor meanwhile.
  const NodeKey key = KeyOf(id);
  ChannelStats s = Stat(id, c);
  const uint32_t brick = nodes_[id].brick;
  if (brick != 0) {
    const Box valid = geometry_.ValidBox(key);
    OCTO_ASSIGN_OR_RETURN(BrickHandle handle, pool_.Pin(brick));
    const std::byte* data = std::as_const(handle).data().data();
    const int bps = geometry_.bytes_per_sample();
    const size_t stride = static_cast<size_t>(channels_) * bps;
    uint32_t lo = 65535, hi = 0;
    uint64_t sum = 0;
    for (int64_t z = valid.lo[2]; z < valid.hi[2]; ++z) {
      for (int64_t y = valid.lo[1]; y < valid.hi[1]; ++y) {
        const std::byte* row = data + geometry_.StoredByteOffset(key, {valid.lo[0], y, z}, c);
        for (int64_t x = 0; x < valid.Extent(0); ++x) {
          const uint32_t v = LoadSample(row + x * stride, bps);
          lo = std::min(lo, v);
          hi = std::max(hi, v);
          sum += v;
        }
      }
    }
    s.min = static_cast<uint16_t>(lo);
    s.max = static_cast<uint16_t>(hi);
    s.avg = static_cast<double>(sum) / static_cast<double>(valid.VoxelCount());
  } else {
    s.min = s.max = Uniform(id, c);
  }
  // A childless node's subtree is itself, unless its children were deleted as homogeneous: then
  // the stored subtree range (their data's) stays.
  const bool children_deleted =
      key.level > 0 && nodes_[id].child_group == 0 && (nodes_[id].flags & kComplete) != 0;
  if (!children_deleted) {
    s.sub_min = s.min;
    s.sub_max = s.max;
  } else {
    s.sub_min = std::min(s.sub_min, s.min);
    s.sub_max = std::max(s.sub_max, s.max);
  }
  bool complete = (nodes_[id].flags & kComplete) != 0;
  const uint32_t group = nodes_[id].child_group;
  if (group != 0) {
    complete = true;
    for (uint32_t child = group * 8; child < group * 8 + 8; ++child) {
      if ((nodes_[child].flags & kComplete) == 0) complete = false;
      if ((nodes_[child].flags & kVirtual) != 0) continue;  // Virtual voxels never count.
      s.sub_min = std::min(s.sub_min, Stat(child, c).sub_min);
      s.sub_max = std::max(s.sub_max, Stat(child, c).sub_max);
    }
  }
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    Stat(id, c) = s;
    if (complete) nodes_[id].flags |= kComplete;
  }
  changes_.Append(id, NodeChangeKind::kUpdated);
  if (!complete) return Status::Ok();  // Incomplete nodes are never pruned.

  bool brick_homogeneous = true, subtree_homogeneous = true;
  for (int ch = 0; ch < channels_; ++ch) {
    const ChannelStats& t = Stat(id, ch);
    if (t.max - t.min > static_cast<int64_t>(tolerance_[ch])) brick_homogeneous = false;
    if (t.sub_max - t.sub_min > static_cast<int64_t>(tolerance_[ch])) subtree_homogeneous = false;
  }
  if (brick != 0 && brick_homogeneous) OCTO_RETURN_IF_ERROR(DropBrick(id, key));
  // The subtree statistics keep describing the deleted subtree's data (its true range), so an
  // ancestor's homogeneity test sees the same numbers whenever the deletion happened.
  if (group != 0 && subtree_homogeneous) OCTO_RETURN_IF_ERROR(DeleteChildren(id, key));
  return Status::Ok();
}

// --------------------------------------------------------------------------------------------
// Insert.

Status Octree::Insert(int channel, const Box& box, std::span<const std::byte> data) {
  if (channel < 0 || channel >= channels_) {
    return InvalidArgumentError("octree: channel " + std::to_string(channel) + " of " +
                                std::to_string(channels_));
  }
  if (box.empty() || !geometry_.ValidExtent(0).ContainsBox(box)) {
    return OutOfRangeError("octree: block " + box.ToString() + " is empty or outside the volume " +
                           geometry_.ValidExtent(0).ToString());
  }
  const int bps = geometry_.bytes_per_sample();
  const uint64_t voxels = box.VoxelCount();
  if (data.size() != voxels * static_cast<uint64_t>(bps)) {
    return InvalidArgumentError("octree: block " + box.ToString() + " needs " +
                                std::to_string(voxels * bps) + " bytes, got " +
                                std::to_string(data.size()));
  }
  std::lock_guard<std::mutex> insert_lock(insert_mu_);
  std::vector<uint16_t> values(voxels);
  for (uint64_t i = 0; i < voxels; ++i) values[i] = LoadSample(data.data() + i * bps, bps);

  const int root = geometry_.root_level();
  std::vector<std::vector<uint32_t>> touched(root + 1);
  // Step 1: the leaves.
  OCTO_RETURN_IF_ERROR(WriteLevel(0, box, channel, values, &touched[0]));
  // Step 2: the path to the root, one level at a time.
  Box dirty = box;
  std::vector<uint16_t> children;
  for (int level = 1; level <= root; ++level) {
    const Box cover = CoarsenBox(dirty).Intersect(geometry_.ValidExtent(level));
    const Box child_box = RefineBox(cover).Intersect(geometry_.ValidExtent(level - 1));
    children.resize(child_box.VoxelCount());
    OCTO_RETURN_IF_ERROR(ReadRepresentation(level - 1, child_box, channel, children.data()));
    values.assign(cover.VoxelCount(), 0);
    size_t i = 0;
    for (int64_t z = cover.lo[2]; z < cover.hi[2]; ++z) {
      for (int64_t y = cover.lo[1]; y < cover.hi[1]; ++y) {
        for (int64_t x = cover.lo[0]; x < cover.hi[0]; ++x, ++i) {
          // Mean of the VALID children (child_box is clipped to the valid extent).
          const Box group =
              Box{{2 * x, 2 * y, 2 * z}, {2 * x + 2, 2 * y + 2, 2 * z + 2}}.Intersect(child_box);
          uint64_t sum = 0;
          ForEachIndex(group, [&](const Vec3& p) {
            sum += children[BufferIndex(child_box, p[0], p[1], p[2])];
          });
          const uint64_t n = group.VoxelCount();
          values[i] = static_cast<uint16_t>((sum + n / 2) / n);
        }
      }
    }
    OCTO_RETURN_IF_ERROR(WriteLevel(level, cover, channel, values, &touched[level]));
    dirty = cover;
  }
  // Step 3: statistics, completeness and pruning, bottom-up so children are final first.
  for (int level = 0; level <= root; ++level) {
    std::vector<uint32_t>& ids = touched[level];
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    for (uint32_t id : ids) OCTO_RETURN_IF_ERROR(UpdateNode(id, channel));
  }
  return Status::Ok();
}

}  // namespace octoscope::octree
