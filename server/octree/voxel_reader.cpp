#include "octree/voxel_reader.h"

#include <cstring>
#include <functional>
#include <optional>
#include <string>

namespace octoscope::octree {
namespace {

// One terminal node (no children) over a level-0 region: its key, its state, and its brick's
// bytes (empty when it has none).
struct Terminal {
  NodeKey key;
  const NodeSnapshot* node = nullptr;
  Box region;  // Level-0 voxels: the node's box within the query box and the valid extent.
  std::span<const std::byte> brick;
};

// Calls `visit` for every terminal node whose level-0 box meets `box`, depth first.
Status Walk(const Octree& tree, const Box& box, const std::function<void(const Terminal&)>& visit,
            std::stop_token stop = {}) {
  const BrickGeometry& g = tree.geometry();
  const Box target = box.Intersect(g.ValidExtent(0));
  std::vector<std::byte> brick(g.brick_bytes());
  std::vector<NodeKey> stack{g.RootKey()};
  while (!stack.empty()) {
    if (stop.stop_requested()) return CancelledError("reading voxels: cancelled");
    const NodeKey key = stack.back();
    stack.pop_back();
    const Box region = g.NodeBoxLevel0(key).Intersect(target);
    if (region.empty()) continue;
    const std::optional<NodeSnapshot> node = tree.GetNode(key);
    if (!node) {
      return UnavailableError("octree changed while reading voxels (node " + key.ToString() +
                              " vanished)");
    }
    if (node->has_children()) {
      for (int octant = 7; octant >= 0; --octant) stack.push_back(ChildKey(key, octant));
      continue;
    }
    Terminal t{key, &*node, region, {}};
    if (node->has_brick()) {
      const Status read = tree.ReadBrick(node->id, brick);
      if (read.code() == StatusCode::kNotFound) {
        return UnavailableError("octree changed while reading voxels (brick of " + key.ToString() +
                                " dropped)");
      }
      OCTO_RETURN_IF_ERROR(read);
      t.brick = brick;
    }
    visit(t);
  }
  return Status::Ok();
}

uint16_t Sample(const BrickGeometry& g, const NodeKey& key, std::span<const std::byte> brick,
                const Vec3& level_voxel, int c) {
  const uint64_t offset = g.StoredByteOffset(key, level_voxel, c);
  if (g.bytes_per_sample() == 1) return std::to_integer<uint8_t>(brick[offset]);
  uint16_t v;
  std::memcpy(&v, &brick[offset], 2);
  return v;
}

// The node's value at level-0 voxel p (its brick at p's position in its level, or its uniform
// value).
uint16_t ValueAt(const BrickGeometry& g, const Terminal& t, const Vec3& p, int c) {
  if (t.brick.empty()) return t.node->channels[c].min;
  const int l = t.key.level;
  return Sample(g, t.key, t.brick, {p[0] >> l, p[1] >> l, p[2] >> l}, c);
}

}  // namespace

Status ReadVoxels(const Octree& tree, int channel, const Box& box, std::span<uint16_t> out) {
  const BrickGeometry& g = tree.geometry();
  if (channel < 0 || channel >= g.channels()) {
    return InvalidArgumentError("read voxels: channel " + std::to_string(channel) + " of " +
                                std::to_string(g.channels()));
  }
  if (box.empty() || !g.ValidExtent(0).ContainsBox(box)) {
    return InvalidArgumentError("read voxels: box " + box.ToString() + " outside the volume");
  }
  if (out.size() != box.VoxelCount()) {
    return InvalidArgumentError("read voxels: " + std::to_string(out.size()) + " values for " +
                                std::to_string(box.VoxelCount()) + " voxels");
  }
  const int64_t sx = box.Extent(0), sy = box.Extent(1);
  return Walk(tree, box, [&](const Terminal& t) {
    for (int64_t z = t.region.lo[2]; z < t.region.hi[2]; ++z) {
      for (int64_t y = t.region.lo[1]; y < t.region.hi[1]; ++y) {
        uint16_t* row = out.data() + ((z - box.lo[2]) * sy + (y - box.lo[1])) * sx - box.lo[0];
        for (int64_t x = t.region.lo[0]; x < t.region.hi[0]; ++x) {
          row[x] = ValueAt(g, t, {x, y, z}, channel);
        }
      }
    }
  });
}

Status CountVoxels(const Octree& tree, std::vector<std::vector<uint64_t>>& counts,
                   std::stop_token stop) {
  const BrickGeometry& g = tree.geometry();
  const size_t bins = g.bytes_per_sample() == 1 ? 256 : 65536;
  if (counts.size() != static_cast<size_t>(g.channels())) {
    return InvalidArgumentError("count voxels: counts for another channel count");
  }
  for (const auto& c : counts) {
    if (c.size() != bins) return InvalidArgumentError("count voxels: wrong number of bins");
  }
  return Walk(
      tree, g.ValidExtent(0),
      [&](const Terminal& t) {
        if (t.brick.empty()) {
          // Uniform: every valid voxel of the region has the node's value.
          const uint64_t n = t.region.VoxelCount();
          for (int c = 0; c < g.channels(); ++c) counts[c][t.node->channels[c].min] += n;
          return;
        }
        for (int64_t z = t.region.lo[2]; z < t.region.hi[2]; ++z) {
          for (int64_t y = t.region.lo[1]; y < t.region.hi[1]; ++y) {
            for (int64_t x = t.region.lo[0]; x < t.region.hi[0]; ++x) {
              for (int c = 0; c < g.channels(); ++c) ++counts[c][ValueAt(g, t, {x, y, z}, c)];
            }
          }
        }
      },
      stop);
}

}  // namespace octoscope::octree
