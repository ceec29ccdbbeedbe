// Octree::Save / Octree::Load: the node table file (docs/octree_format.md, "Node table").
#include <algorithm>
#include <bit>
#include <cstring>
#include <string>
#include <vector>

#include "octree/binary_stream.h"
#include "octree/node_encoding.h"
#include "octree/octree.h"

namespace octoscope::octree {
namespace {

constexpr char kMagic[8] = {'O', 'C', 'T', 'O', 'T', 'R', 'E', 'E'};
constexpr uint32_t kEndMarker = 0x21444e45;  // "END!" little-endian.

}  // namespace

Status Octree::Save(std::ostream& out) const {
  std::lock_guard<std::mutex> insert_lock(insert_mu_);  // A stable progress_ and table.
  std::shared_lock<std::shared_mutex> lock(mu_);
  out.write(kMagic, sizeof(kMagic));
  PutLe<uint32_t>(out, kFormatVersion);
  for (int a = 0; a < 3; ++a)
    PutLe<uint64_t>(out, static_cast<uint64_t>(geometry_.volume_size()[a]));
  for (int a = 0; a < 3; ++a)
    PutLe<uint64_t>(out, static_cast<uint64_t>(geometry_.brick_size()[a]));
  PutLe<uint32_t>(out, static_cast<uint32_t>(channels_));
  PutLe<uint32_t>(out, static_cast<uint32_t>(geometry_.bytes_per_sample()));
  for (int c = 0; c < channels_; ++c) {
    PutLe<uint32_t>(out, tolerance_[c]);
    PutLe<uint16_t>(out, background_[c]);
  }
  PutLe<uint32_t>(out, static_cast<uint32_t>(group_parent_.size()));
  for (uint32_t parent : group_parent_) PutLe<uint32_t>(out, parent);
  for (const NodeRecord& r : nodes_) {
    PutLe<uint32_t>(out, r.child_group);
    PutLe<uint32_t>(out, r.brick);
    PutLe<uint8_t>(out, r.level);
    PutLe<uint8_t>(out, r.flags);
  }
  for (const ChannelStats& s : stats_) {
    PutLe<uint16_t>(out, s.min);
    PutLe<uint16_t>(out, s.max);
    PutLe<uint16_t>(out, s.sub_min);
    PutLe<uint16_t>(out, s.sub_max);
    PutLe<uint64_t>(out, std::bit_cast<uint64_t>(s.avg));
  }
  const BrickPool::State pool = pool_.ExportState();
  PutLe<uint32_t>(out, pool.next_id);
  PutLe<uint32_t>(out, static_cast<uint32_t>(pool.free_ids.size()));
  for (uint32_t id : pool.free_ids) PutLe<uint32_t>(out, id);
  // Leaf progress, in ascending node order so that equal trees give equal files.
  std::vector<uint32_t> leaves;
  for (const auto& [id, progress] : progress_) leaves.push_back(id);
  std::sort(leaves.begin(), leaves.end());
  PutLe<uint32_t>(out, static_cast<uint32_t>(leaves.size()));
  for (uint32_t id : leaves) {
    const LeafProgress& p = progress_.at(id);
    PutLe<uint32_t>(out, id);
    PutLe<uint64_t>(out, p.complete_channels);
    for (int c = 0; c < channels_; ++c) {
      const bool present = c < static_cast<int>(p.channels.size()) && p.channels[c] != nullptr;
      PutLe<uint8_t>(out, present ? 1 : 0);
      if (present) p.channels[c]->Save(out);
    }
  }
  PutLe<uint32_t>(out, kEndMarker);
  if (!out) return IoError("octree: writing the node table failed");
  return Status::Ok();
}

Result<std::unique_ptr<Octree>> Octree::Load(std::istream& in, paging::PageCache* cache) {
  char magic[sizeof(kMagic)] = {};
  in.read(magic, sizeof(magic));
  if (in.gcount() != static_cast<std::streamsize>(sizeof(magic)) ||
      std::memcmp(magic, kMagic, sizeof(kMagic)) != 0) {
    return CorruptError("octree node table: bad magic (not an Octoscope node table)");
  }
  BinaryReader r(in);
  const uint32_t version = r.Get<uint32_t>();
  if (r.ok() && version != kFormatVersion) {
    return UnsupportedError("octree node table: version " + std::to_string(version) +
                            ", this build reads " + std::to_string(kFormatVersion));
  }
  BrickGeometry::Params params;
  // Out-of-range values become -1 so that BrickGeometry::Create rejects them by name.
  auto axis = [&r]() -> int64_t {
    const uint64_t v = r.Get<uint64_t>();
    return v > (uint64_t{1} << 31) ? -1 : static_cast<int64_t>(v);
  };
  auto small = [&r]() -> int {
    const uint32_t v = r.Get<uint32_t>();
    return v > 0xffff ? -1 : static_cast<int>(v);
  };
  for (int a = 0; a < 3; ++a) params.volume_size[a] = axis();
  for (int a = 0; a < 3; ++a) params.brick_size[a] = axis();
  params.channels = small();
  params.bytes_per_sample = small();
  if (!r.ok()) return CorruptError("octree node table: truncated header");
  auto geometry = BrickGeometry::Create(params);
  if (!geometry.ok()) return geometry.status().WithContext("octree node table");
  OctreeOptions options;
  options.brick_size = params.brick_size;
  for (int c = 0; c < params.channels; ++c) {
    options.homogeneity_tolerance.push_back(r.Get<uint32_t>());
    options.background.push_back(r.Get<uint16_t>());
  }
  if (!r.ok()) return CorruptError("octree node table: truncated channel options");
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<Octree> tree, CreateImpl(*geometry, options, cache));
  const int channels = tree->channels_;

  const uint32_t groups = r.Get<uint32_t>();
  if (!r.ok() || groups == 0 || groups > MaxChildGroups(*geometry)) {
    return CorruptError("octree node table: " + std::to_string(groups) +
                        " child groups, outside [1, " + std::to_string(MaxChildGroups(*geometry)) +
                        "] for " + geometry->ToString());
  }
  // Records are appended as they are read, so a lying count cannot make us allocate more than
  // the stream actually holds.
  for (uint32_t g = 0; g < groups && r.ok(); ++g) tree->group_parent_.push_back(r.Get<uint32_t>());
  for (uint64_t n = 0; n < uint64_t{groups} * 8 && r.ok(); ++n) {
    NodeRecord rec;
    rec.child_group = r.Get<uint32_t>();
    rec.brick = r.Get<uint32_t>();
    rec.level = r.Get<uint8_t>();
    rec.flags = r.Get<uint8_t>();
    tree->nodes_.push_back(rec);
  }
  for (uint64_t n = 0; n < uint64_t{groups} * 8 * channels && r.ok(); ++n) {
    ChannelStats s;
    s.min = r.Get<uint16_t>();
    s.max = r.Get<uint16_t>();
    s.sub_min = r.Get<uint16_t>();
    s.sub_max = r.Get<uint16_t>();
    s.avg = std::bit_cast<double>(r.Get<uint64_t>());
    tree->stats_.push_back(s);
  }
  BrickPool::State pool;
  pool.next_id = r.Get<uint32_t>();
  const uint32_t free_bricks = r.Get<uint32_t>();
  if (!r.ok()) return CorruptError("octree node table: truncated node records");
  if (pool.next_id == 0 || free_bricks >= pool.next_id ||
      pool.next_id - 1 - free_bricks > uint64_t{groups} * 8) {
    return CorruptError("octree node table: " + std::to_string(free_bricks) + " free bricks of " +
                        std::to_string(pool.next_id - 1));
  }
  for (uint32_t i = 0; i < free_bricks && r.ok(); ++i) pool.free_ids.push_back(r.Get<uint32_t>());
  if (!r.ok()) return CorruptError("octree node table: truncated brick free list");
  OCTO_RETURN_IF_ERROR(tree->pool_.ImportState(pool).WithContext("octree node table"));

  // Structure: walk the tree from the root, checking every link, level and brick.
  auto& nodes = tree->nodes_;
  if (tree->group_parent_[0] != 0 || nodes[0].flags != (nodes[0].flags & (kLive | kComplete)) ||
      (nodes[0].flags & kLive) == 0 || nodes[0].level != geometry->root_level()) {
    return CorruptError("octree node table: bad root record");
  }
  std::vector<bool> group_seen(groups, false);
  std::vector<bool> brick_seen(pool.next_id, false);
  group_seen[0] = true;
  std::vector<uint32_t> stack{0};
  uint64_t live_groups = 1;
  while (!stack.empty()) {
    const uint32_t id = stack.back();
    stack.pop_back();
    const NodeRecord& rec = nodes[id];
    const NodeKey key = tree->KeyOf(id);
    const bool is_virtual = geometry->IsVirtual(key);
    if ((rec.flags & ~(kLive | kVirtual | kComplete)) != 0 || (rec.flags & kLive) == 0 ||
        ((rec.flags & kVirtual) != 0) != is_virtual) {
      return CorruptError("octree node table: node " + std::to_string(id) + " has bad flags");
    }
    if (rec.brick != 0) {
      if (is_virtual || !tree->pool_.IsLive(rec.brick) || brick_seen[rec.brick]) {
        return CorruptError("octree node table: node " + std::to_string(id) + " has bad brick " +
                            std::to_string(rec.brick));
      }
      brick_seen[rec.brick] = true;
    }
    if (rec.child_group != 0) {
      const uint32_t g = rec.child_group;
      if (is_virtual || rec.level == 0 || g >= groups || group_seen[g] ||
          tree->group_parent_[g] != id) {
        return CorruptError("octree node table: node " + std::to_string(id) +
                            " has bad child group " + std::to_string(g));
      }
      group_seen[g] = true;
      ++live_groups;
      for (uint32_t child = g * 8; child < g * 8 + 8; ++child) {
        if (nodes[child].level + 1 != rec.level) {
          return CorruptError("octree node table: node " + std::to_string(child) + " has level " +
                              std::to_string(nodes[child].level));
        }
        stack.push_back(child);
      }
    }
  }
  for (uint32_t g = 1; g < groups; ++g) {
    if (group_seen[g]) continue;
    if (tree->group_parent_[g] != kFreeGroup) {
      return CorruptError("octree node table: group " + std::to_string(g) + " is unreachable");
    }
    for (uint32_t n = g * 8; n < g * 8 + 8; ++n) nodes[n] = NodeRecord{};
    tree->free_groups_.insert(g);
  }
  if (live_groups + tree->free_groups_.size() != groups) {
    return CorruptError("octree node table: group bookkeeping inconsistent");
  }

  const uint32_t leaves = r.Get<uint32_t>();
  if (!r.ok() || leaves > uint64_t{groups} * 8) {
    return CorruptError("octree node table: bad leaf progress count");
  }
  for (uint32_t i = 0; i < leaves; ++i) {
    const uint32_t id = r.Get<uint32_t>();
    LeafProgress p;
    p.complete_channels = r.Get<uint64_t>();
    if (!r.ok() || !tree->IsLiveId(id) || nodes[id].level != 0 ||
        (nodes[id].flags & (kComplete | kVirtual)) != 0 || tree->progress_.count(id) != 0 ||
        (channels < 64 && (p.complete_channels >> channels) != 0)) {
      return CorruptError("octree node table: bad leaf progress record for node " +
                          std::to_string(id));
    }
    const Box valid = geometry->ValidBox(tree->KeyOf(id));
    p.channels.resize(channels);
    for (int c = 0; c < channels; ++c) {
      const uint8_t present = r.Get<uint8_t>();
      if (!r.ok() || present > 1 || (present == 1 && ((p.complete_channels >> c) & 1) != 0)) {
        return CorruptError("octree node table: bad coverage flag for node " + std::to_string(id));
      }
      if (present == 0) continue;
      auto coverage =
          WriteCoverage::Load(in, Vec3{valid.Extent(0), valid.Extent(1), valid.Extent(2)});
      if (!coverage.ok()) return coverage.status().WithContext("octree node table");
      p.channels[c] = std::make_unique<WriteCoverage>(std::move(*coverage));
    }
    tree->progress_.emplace(id, std::move(p));
  }
  if (r.Get<uint32_t>() != kEndMarker || !r.ok()) {
    return CorruptError("octree node table: missing end marker");
  }
  return tree;
}

}  // namespace octoscope::octree
