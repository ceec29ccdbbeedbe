// Test helpers for the octree: an independent brute-force model of what the octree must hold
// (a mipmap computed naively from the source voxels), a canonical dump of a tree's structure that
// does not depend on node or brick ids, and a small fixture owning a page store and cache.
#ifndef OCTOSCOPE_TESTS_OCTREE_OCTREE_REFERENCE_H_
#define OCTOSCOPE_TESTS_OCTREE_OCTREE_REFERENCE_H_

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "octree/brick_geometry.h"
#include "octree/octree.h"
#include "paging/memory_page_store.h"
#include "paging/page_cache.h"

namespace octoscope::octree::testing {

// A dense multi-channel volume of uint16 samples (the test's source of truth).
struct SourceVolume {
  Vec3 size{1, 1, 1};
  int channels = 1;
  std::vector<std::vector<uint16_t>> data;  // [channel][(z*sy + y)*sx + x]

  SourceVolume(Vec3 s, int c)
      : size(s), channels(c), data(c, std::vector<uint16_t>(s[0] * s[1] * s[2])) {}
  size_t Index(int64_t x, int64_t y, int64_t z) const {
    return static_cast<size_t>((z * size[1] + y) * size[0] + x);
  }
  uint16_t& at(int c, int64_t x, int64_t y, int64_t z) { return data[c][Index(x, y, z)]; }
  uint16_t at(int c, int64_t x, int64_t y, int64_t z) const { return data[c][Index(x, y, z)]; }

  // The samples of `box` for channel c in the stored type, x fastest.
  std::vector<std::byte> Block(int c, const Box& box, int bps) const {
    std::vector<std::byte> out(box.VoxelCount() * bps);
    size_t i = 0;
    for (int64_t z = box.lo[2]; z < box.hi[2]; ++z)
      for (int64_t y = box.lo[1]; y < box.hi[1]; ++y)
        for (int64_t x = box.lo[0]; x < box.hi[0]; ++x, ++i) {
          const uint16_t v = at(c, x, y, z);
          if (bps == 1) {
            out[i] = static_cast<std::byte>(v);
          } else {
            std::memcpy(&out[2 * i], &v, 2);
          }
        }
    return out;
  }
};

// A test volume with structure: constant regions (so pruning happens), a smooth ramp and a noisy
// blob (so bricks survive). Values fit `bps` bytes.
inline SourceVolume MakePatternVolume(Vec3 size, int channels, int bps, uint32_t seed) {
  SourceVolume v(size, channels);
  std::mt19937 rng(seed);
  const int vmax = bps == 1 ? 255 : 65535;
  for (int c = 0; c < channels; ++c) {
    for (int64_t z = 0; z < size[2]; ++z)
      for (int64_t y = 0; y < size[1]; ++y)
        for (int64_t x = 0; x < size[0]; ++x) {
          int value;
          const double dx = x - size[0] * 0.6, dy = y - size[1] * 0.4, dz = z - size[2] * 0.5;
          const double r2 = dx * dx + dy * dy + dz * dz;
          if (r2 < 0.06 * size[0] * size[0]) {
            value = static_cast<int>(rng() % static_cast<uint32_t>(vmax + 1));  // Noisy blob.
          } else if (x < size[0] / 3) {
            value = 10 * (c + 1);  // Constant slab.
          } else if (y < size[1] / 2) {
            value = 0;
          } else {
            value = static_cast<int>((x + 2 * y + 3 * z) * (c + 1)) % (vmax + 1);  // Ramp.
          }
          v.at(c, x, y, z) = static_cast<uint16_t>(value);
        }
  }
  return v;
}

// The naive mipmap: level 0 = source (or background where `written` is false), each parent the
// integer mean, round half up, of its VALID children. [level][channel][voxel].
struct ReferencePyramid {
  std::vector<Vec3> sizes;
  std::vector<std::vector<std::vector<uint16_t>>> levels;

  uint16_t at(int level, int c, const Vec3& p) const {
    const Vec3& s = sizes[level];
    return levels[level][c][static_cast<size_t>((p[2] * s[1] + p[1]) * s[0] + p[0])];
  }
  bool Valid(int level, const Vec3& p) const {
    for (int a = 0; a < 3; ++a)
      if (p[a] < 0 || p[a] >= sizes[level][a]) return false;
    return true;
  }
};

inline ReferencePyramid BuildReference(const SourceVolume& src, int level_count,
                                       const std::vector<uint16_t>& background,
                                       const std::vector<bool>* written = nullptr) {
  ReferencePyramid ref;
  ref.sizes.push_back(src.size);
  ref.levels.emplace_back(src.channels);
  for (int c = 0; c < src.channels; ++c) {
    ref.levels[0][c] = src.data[c];
    if (written != nullptr) {
      for (size_t i = 0; i < src.data[c].size(); ++i)
        if (!(*written)[i]) ref.levels[0][c][i] = background[c];
    }
  }
  for (int l = 1; l < level_count; ++l) {
    const Vec3 ps = ref.sizes[l - 1];
    const Vec3 s{(ps[0] + 1) / 2, (ps[1] + 1) / 2, (ps[2] + 1) / 2};
    ref.sizes.push_back(s);
    ref.levels.emplace_back(src.channels, std::vector<uint16_t>(s[0] * s[1] * s[2]));
    for (int c = 0; c < src.channels; ++c)
      for (int64_t z = 0; z < s[2]; ++z)
        for (int64_t y = 0; y < s[1]; ++y)
          for (int64_t x = 0; x < s[0]; ++x) {
            uint64_t sum = 0, n = 0;
            for (int64_t k = 2 * z; k < std::min(2 * z + 2, ps[2]); ++k)
              for (int64_t j = 2 * y; j < std::min(2 * y + 2, ps[1]); ++j)
                for (int64_t i = 2 * x; i < std::min(2 * x + 2, ps[0]); ++i) {
                  sum += ref.at(l - 1, c, {i, j, k});
                  ++n;
                }
            ref.levels[l][c][static_cast<size_t>((z * s[1] + y) * s[0] + x)] =
                static_cast<uint16_t>((sum + n / 2) / n);
          }
  }
  return ref;
}

// Min / max / mean of a reference level over a box (clipped to the level's valid extent).
struct RangeStats {
  uint32_t min = 0xffffffff, max = 0;
  double avg = 0;
  uint64_t count = 0;
};
inline RangeStats ReferenceStats(const ReferencePyramid& ref, int level, int c, const Box& box) {
  RangeStats r;
  uint64_t sum = 0;
  for (int64_t z = box.lo[2]; z < box.hi[2]; ++z)
    for (int64_t y = box.lo[1]; y < box.hi[1]; ++y)
      for (int64_t x = box.lo[0]; x < box.hi[0]; ++x) {
        if (!ref.Valid(level, {x, y, z})) continue;
        const uint32_t v = ref.at(level, c, {x, y, z});
        r.min = std::min(r.min, v);
        r.max = std::max(r.max, v);
        sum += v;
        ++r.count;
      }
  if (r.count > 0) r.avg = static_cast<double>(sum) / static_cast<double>(r.count);
  return r;
}

// One node of a canonical dump: everything observable except ids.
struct NodeDump {
  NodeKey key;
  bool has_children = false;
  bool has_brick = false;
  bool is_virtual = false;
  bool complete = false;
  std::vector<ChannelSummary> channels;
  std::vector<std::byte> brick;  // Empty when no brick.

  bool operator==(const NodeDump&) const = default;
};

inline std::string Describe(const NodeDump& d) {
  std::string s = d.key.ToString() + (d.has_children ? " children" : "") +
                  (d.has_brick ? " brick" : "") + (d.is_virtual ? " virtual" : "") +
                  (d.complete ? " complete" : "");
  for (const ChannelSummary& c : d.channels) {
    s += " [" + std::to_string(c.min) + "," + std::to_string(c.max) + " sub " +
         std::to_string(c.subtree_min) + "," + std::to_string(c.subtree_max) + " avg " +
         std::to_string(c.avg) + "]";
  }
  return s;
}

// Depth-first dump by key (children in octant order).
inline std::vector<NodeDump> DumpTree(const Octree& tree) {
  std::vector<NodeDump> out;
  std::vector<NodeKey> stack{tree.geometry().RootKey()};
  while (!stack.empty()) {
    const NodeKey key = stack.back();
    stack.pop_back();
    std::optional<NodeSnapshot> node = tree.GetNode(key);
    if (!node.has_value()) {
      ADD_FAILURE() << "node " << key.ToString() << " listed by its parent is missing";
      continue;
    }
    NodeDump d;
    d.key = key;
    d.has_children = node->has_children();
    d.has_brick = node->has_brick();
    d.is_virtual = node->is_virtual;
    d.complete = node->complete;
    d.channels = node->channels;
    if (d.has_brick) {
      d.brick.resize(tree.geometry().brick_bytes());
      Status st = tree.ReadBrick(node->id, d.brick);
      EXPECT_TRUE(st.ok()) << st.ToString();
    }
    out.push_back(std::move(d));
    if (node->has_children()) {
      for (int octant = 7; octant >= 0; --octant) stack.push_back(ChildKey(key, octant));
    }
  }
  return out;
}

inline void ExpectSameTree(const std::vector<NodeDump>& a, const std::vector<NodeDump>& b,
                           const std::string& what) {
  ASSERT_EQ(a.size(), b.size()) << what << ": node counts differ";
  for (size_t i = 0; i < a.size(); ++i) {
    if (!(a[i] == b[i])) {
      ADD_FAILURE() << what << ": node " << i << " differs:\n  " << Describe(a[i]) << "\n  "
                    << Describe(b[i])
                    << (a[i].brick != b[i].brick ? "\n  (brick bytes differ)" : "");
      return;
    }
  }
}

// A sample of a stored brick.
inline uint16_t BrickSample(const BrickGeometry& g, const NodeKey& key,
                            const std::vector<std::byte>& brick, const Vec3& p, int c) {
  const uint64_t off = g.StoredByteOffset(key, p, c);
  if (g.bytes_per_sample() == 1) return std::to_integer<uint8_t>(brick[off]);
  uint16_t v;
  std::memcpy(&v, &brick[off], 2);
  return v;
}

// Geometry parameters: a volume of `size` voxels in bricks of `brick`, `channels` channels of
// `bps`-byte samples.
inline BrickGeometry::Params Params(Vec3 size, Vec3 brick, int channels, int bps) {
  BrickGeometry::Params p;
  p.volume_size = size;
  p.brick_size = brick;
  p.channels = channels;
  p.bytes_per_sample = bps;
  return p;
}

// One box per z plane of a `size` volume, bottom to top.
inline std::vector<Box> ZSlabs(const Vec3& size) {
  std::vector<Box> out;
  for (int64_t z = 0; z < size[2]; ++z) out.push_back(Box{{0, 0, z}, {size[0], size[1], z + 1}});
  return out;
}

// Inserts channel c of `box` from `src`, in the tree's sample size.
inline Status InsertBlock(Octree& tree, const SourceVolume& src, int c, const Box& box) {
  return tree.Insert(c, box, src.Block(c, box, tree.geometry().bytes_per_sample()));
}

// InsertBlock that fails the test (fatally: wrap in ASSERT_NO_FATAL_FAILURE to stop the caller)
// with the status and the box.
inline void InsertBox(Octree& tree, const SourceVolume& src, int c, const Box& box) {
  Status st = InsertBlock(tree, src, c, box);
  ASSERT_TRUE(st.ok()) << st.ToString() << " inserting " << box.ToString();
}

// A page store + cache + octree.
struct TreeFixture {
  std::unique_ptr<paging::MemoryPageStore> store;
  std::unique_ptr<paging::PageCache> cache;
  std::unique_ptr<Octree> tree;

  static TreeFixture Make(const BrickGeometry::Params& params, const OctreeOptions& options,
                          uint64_t page_bytes = 1 << 16, uint64_t budget = 64 << 20) {
    TreeFixture f;
    f.store = std::make_unique<paging::MemoryPageStore>(page_bytes);
    f.cache = std::make_unique<paging::PageCache>(f.store.get(), budget);
    auto geometry = BrickGeometry::Create(params);
    EXPECT_TRUE(geometry.ok()) << geometry.status().ToString();
    auto tree = Octree::Create(*geometry, options, f.cache.get());
    EXPECT_TRUE(tree.ok()) << tree.status().ToString();
    if (tree.ok()) f.tree = std::move(*tree);
    return f;
  }
};

}  // namespace octoscope::octree::testing

#endif  // OCTOSCOPE_TESTS_OCTREE_OCTREE_REFERENCE_H_
