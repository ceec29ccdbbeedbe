// Tests for octree/brick_geometry.h: every derived quantity is checked against a brute-force
// computation (enumerating voxels / nodes of small volumes) or against hand-worked numbers.
#include "octree/brick_geometry.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <set>
#include <unordered_set>
#include <vector>

namespace octoscope::octree {
namespace {

BrickGeometry Make(Vec3 size, Vec3 brick, int channels = 1, int bytes = 2) {
  Result<BrickGeometry> g = BrickGeometry::Create({size, brick, channels, bytes});
  EXPECT_TRUE(g.ok()) << g.status().ToString();
  return *g;
}

// The small geometries every brute-force test runs over: odd sizes, degenerate axes, brick sizes
// per axis, brick size 2, volume smaller than one brick, exact powers of two.
std::vector<BrickGeometry> SmallGeometries() {
  return {
      Make({67, 33, 5}, {64, 32, 16}, 2), Make({67, 33, 5}, {2, 2, 2}),
      Make({67, 33, 5}, {4, 6, 2}, 3),    Make({1, 1, 1}, {64, 64, 64}),
      Make({1, 1, 1}, {2, 2, 2}),         Make({1, 1, 9}, {2, 2, 2}),
      Make({1, 1, 17}, {2, 4, 8}),        Make({16, 1, 1}, {4, 2, 2}),
      Make({32, 32, 32}, {8, 8, 8}),      Make({33, 17, 9}, {8, 4, 2}),
      Make({7, 3, 2}, {2, 2, 2}, 4, 1),
  };
}

// Calls f(p) for every voxel of `box`.
template <typename F>
void ForEachVoxel(const Box& box, F f) {
  if (box.empty()) return;
  for (int64_t z = box.lo[2]; z < box.hi[2]; ++z)
    for (int64_t y = box.lo[1]; y < box.hi[1]; ++y)
      for (int64_t x = box.lo[0]; x < box.hi[0]; ++x) f(Vec3{x, y, z});
}

// The valid voxels of every level computed the naive way: level 0 is every voxel of the volume;
// level L+1 is the set of parents {v / 2} of level L's valid voxels.
std::vector<std::set<Vec3>> BruteForceValidSets(const BrickGeometry& g, int levels) {
  std::vector<std::set<Vec3>> sets(levels);
  ForEachVoxel(Box{{0, 0, 0}, g.volume_size()}, [&](const Vec3& p) { sets[0].insert(p); });
  for (int l = 1; l < levels; ++l) {
    for (const Vec3& p : sets[l - 1]) sets[l].insert({p[0] / 2, p[1] / 2, p[2] / 2});
  }
  return sets;
}

// The bounding box of a voxel set (Box{} when empty).
Box BoundingBox(const std::set<Vec3>& voxels) {
  if (voxels.empty()) return Box{};
  Box b{{INT64_MAX, INT64_MAX, INT64_MAX}, {INT64_MIN, INT64_MIN, INT64_MIN}};
  for (const Vec3& p : voxels) {
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::min(b.lo[a], p[a]);
      b.hi[a] = std::max(b.hi[a], p[a] + 1);
    }
  }
  return b;
}

// A dense voxel -> small counter map over a box, for fast brute-force lookups.
class DenseSet {
 public:
  DenseSet(const Box& box, const std::set<Vec3>& members) : box_(box), data_(box.VoxelCount(), 0) {
    for (const Vec3& p : members) {
      if (box_.Contains(p)) data_[Index(p)] = 1;
    }
  }
  uint8_t& at(const Vec3& p) { return data_.at(Index(p)); }
  uint8_t at(const Vec3& p) const { return data_.at(Index(p)); }

 private:
  size_t Index(const Vec3& p) const {
    if (!box_.Contains(p)) return SIZE_MAX;  // at() throws: a test bug, not a silent pass.
    const Vec3 e{box_.Extent(0), box_.Extent(1), box_.Extent(2)};
    return static_cast<size_t>(((p[2] - box_.lo[2]) * e[1] + (p[1] - box_.lo[1])) * e[0] +
                               (p[0] - box_.lo[0]));
  }

  Box box_;
  std::vector<uint8_t> data_;
};

TEST(BoxTest, BasicOperations) {
  const Box b{{1, 2, 3}, {4, 6, 8}};
  EXPECT_FALSE(b.empty());
  EXPECT_EQ(b.VoxelCount(), 3u * 4u * 5u);
  EXPECT_EQ(b.Extent(0), 3);
  EXPECT_TRUE(b.Contains({1, 2, 3}));
  EXPECT_TRUE(b.Contains({3, 5, 7}));
  EXPECT_FALSE(b.Contains({4, 5, 7}));
  EXPECT_FALSE(b.Contains({0, 2, 3}));
  EXPECT_EQ(b.Intersect(Box{{3, 0, 0}, {10, 3, 4}}), (Box{{3, 2, 3}, {4, 3, 4}}));
  EXPECT_TRUE(b.Intersect(Box{{4, 0, 0}, {10, 10, 10}}).empty());  // Touching is not intersecting.
  EXPECT_FALSE(b.Intersects(Box{{4, 0, 0}, {10, 10, 10}}));
  EXPECT_EQ(b.Dilate(1), (Box{{0, 1, 2}, {5, 7, 9}}));
  EXPECT_EQ(b.Dilate(-1), (Box{{2, 3, 4}, {3, 5, 7}}));
  EXPECT_TRUE(b.Dilate(-2).empty());
  const Box empty{{5, 5, 5}, {5, 9, 9}};
  EXPECT_TRUE(empty.empty());
  EXPECT_EQ(empty.VoxelCount(), 0u);
  EXPECT_EQ(empty.Extent(0), 0);
  EXPECT_TRUE(empty.Dilate(1).empty()) << "dilating an empty box must not create voxels";
  EXPECT_TRUE(b.ContainsBox(empty));
  EXPECT_TRUE(b.ContainsBox(b));
  EXPECT_FALSE(b.ContainsBox(b.Dilate(1)));
  EXPECT_EQ(b.ToString(), "[1,4)x[2,6)x[3,8)");
}

TEST(BoxTest, IntersectMatchesVoxelEnumeration) {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int64_t> coord(-4, 6), extent(-1, 5);
  for (int trial = 0; trial < 500; ++trial) {
    Box a, b;
    for (int k = 0; k < 3; ++k) {
      a.lo[k] = coord(rng);
      a.hi[k] = a.lo[k] + extent(rng);
      b.lo[k] = coord(rng);
      b.hi[k] = b.lo[k] + extent(rng);
    }
    uint64_t common = 0;
    ForEachVoxel(Box{{-5, -5, -5}, {12, 12, 12}}, [&](const Vec3& p) {
      const bool in_both = a.Contains(p) && b.Contains(p);
      common += in_both;
      EXPECT_EQ(a.Intersect(b).Contains(p), in_both);
    });
    EXPECT_EQ(a.Intersect(b).VoxelCount(), common);
    EXPECT_EQ(a.Intersects(b), common > 0);
    EXPECT_EQ(a.ContainsBox(b), b.empty() || a.Intersect(b).VoxelCount() == b.VoxelCount());
  }
}

TEST(BoxTest, FloorAndCeilDivisionMatchRealDivision) {
  for (int64_t n = -50; n <= 50; ++n) {
    for (int64_t d = 1; d <= 9; ++d) {
      // Brute force: the largest q with q*d <= n, the smallest q with q*d >= n.
      int64_t floor_q = -100;
      while ((floor_q + 1) * d <= n) ++floor_q;
      int64_t ceil_q = 100;
      while ((ceil_q - 1) * d >= n) --ceil_q;
      EXPECT_EQ(FloorDiv(n, d), floor_q) << n << "/" << d;
      EXPECT_EQ(CeilDiv(n, d), ceil_q) << n << "/" << d;
    }
  }
}

TEST(BoxTest, CoarsenAndRefineMatchVoxelEnumeration) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int64_t> coord(-9, 20);
  for (int trial = 0; trial < 150; ++trial) {
    Box box;
    for (int a = 0; a < 3; ++a) {
      box.lo[a] = coord(rng);
      box.hi[a] = box.lo[a] + std::uniform_int_distribution<int64_t>(0, 7)(rng);
    }
    for (int s = 0; s <= 3; ++s) {
      // Coarsen: the parents (at s levels up) of the box's voxels, with floor for negatives.
      std::set<Vec3> parents;
      const int64_t d = int64_t{1} << s;
      ForEachVoxel(box, [&](const Vec3& p) {
        parents.insert({FloorDiv(p[0], d), FloorDiv(p[1], d), FloorDiv(p[2], d)});
      });
      const Box coarse = CoarsenBox(box, s);
      EXPECT_EQ(coarse, BoundingBox(parents)) << box.ToString() << " s=" << s;
      // The parent set of a box is itself a box.
      EXPECT_EQ(coarse.VoxelCount(), parents.size());
      // Refine: exactly the voxels whose parent lies in the box.
      const Box fine = RefineBox(box, s);
      EXPECT_EQ(fine.VoxelCount(), box.VoxelCount() << (3 * s));
      if (!box.empty()) {
        EXPECT_EQ(CoarsenBox(fine, s), box);
        uint64_t mismatches = 0;
        ForEachVoxel(fine.Dilate(1), [&](const Vec3& p) {
          const Vec3 parent{FloorDiv(p[0], d), FloorDiv(p[1], d), FloorDiv(p[2], d)};
          mismatches += fine.Contains(p) != box.Contains(parent);
        });
        EXPECT_EQ(mismatches, 0u) << box.ToString() << " s=" << s;
      } else {
        EXPECT_TRUE(coarse.empty());
        EXPECT_TRUE(fine.empty());
      }
    }
  }
}

TEST(BrickGeometryTest, CreateRejectsInvalidParameters) {
  struct Case {
    BrickGeometry::Params params;
    const char* expected;  // A fragment of the error message.
  };
  const Case cases[] = {
      {{{0, 5, 5}, {64, 64, 64}, 1, 2}, "volume size x = 0"},
      {{{5, -1, 5}, {64, 64, 64}, 1, 2}, "volume size y = -1"},
      {{{5, 5, 65537}, {64, 64, 64}, 1, 2}, "volume size z = 65537"},
      {{{5, 5, 5}, {63, 64, 64}, 1, 2}, "brick size x = 63"},
      {{{5, 5, 5}, {64, 1, 64}, 1, 2}, "brick size y = 1"},
      {{{5, 5, 5}, {64, 64, 0}, 1, 2}, "brick size z = 0"},
      {{{5, 5, 5}, {64, 64, 2048}, 1, 2}, "brick size z = 2048"},
      {{{5, 5, 5}, {64, 64, 64}, 0, 2}, "0 channels"},
      {{{5, 5, 5}, {64, 64, 64}, kMaxChannels + 1, 2}, "65 channels"},
      {{{5, 5, 5}, {64, 64, 64}, 1, 4}, "4 bytes per sample"},
      {{{5, 5, 5}, {64, 64, 64}, 1, 0}, "0 bytes per sample"},
      // 1026^3 voxels x 1 byte > 2^30.
      {{{5, 5, 5}, {1024, 1024, 1024}, 1, 1}, "exceeds 1073741824 bytes"},
      // 258^3 * 64 channels * 2 bytes > 2^30.
      {{{5, 5, 5}, {256, 256, 256}, 64, 2}, "exceeds"},
  };
  for (const Case& c : cases) {
    Result<BrickGeometry> g = BrickGeometry::Create(c.params);
    ASSERT_FALSE(g.ok()) << c.expected;
    EXPECT_EQ(g.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(g.status().message().find(c.expected), std::string::npos) << g.status().message();
  }
  // The limits themselves are accepted.
  EXPECT_TRUE(BrickGeometry::Create({{65536, 65536, 65536}, {2, 2, 2}, kMaxChannels, 2}).ok());
  EXPECT_TRUE(BrickGeometry::Create({{1, 1, 1}, {1024, 1024, 2}, 1, 1}).ok());
}

TEST(BrickGeometryTest, DefaultsAndDescription) {
  const BrickGeometry g = Make({67, 33, 5}, {64, 32, 16}, 2, 2);
  EXPECT_EQ(g.ToString(), "volume 67x33x5, brick 64x32x16 (+1 apron), 2 ch x 2 B, levels 0..1");
  BrickGeometry::Params defaults;
  EXPECT_EQ(defaults.brick_size, (Vec3{64, 64, 64}));
  EXPECT_EQ(g.params().volume_size, (Vec3{67, 33, 5}));
  EXPECT_EQ(BrickGeometry::Create(g.params()).value(), g);
  EXPECT_EQ(g.RootKey(), (NodeKey{1, {0, 0, 0}}));
}

TEST(BrickGeometryTest, RootLevelIsSmallestCoveringLevel) {
  for (int64_t sx : {1, 2, 3, 63, 64, 65, 200}) {
    for (int64_t sz : {1, 5, 17, 128, 129}) {
      for (const Vec3& brick : {Vec3{2, 2, 2}, Vec3{64, 32, 16}, Vec3{4, 8, 2}, Vec3{64, 64, 64}}) {
        const BrickGeometry g = Make({sx, 7, sz}, brick);
        // Brute force: the smallest R with bs * 2^R >= size on every axis.
        int r = 0;
        while (brick[0] * (int64_t{1} << r) < sx || brick[1] * (int64_t{1} << r) < 7 ||
               brick[2] * (int64_t{1} << r) < sz) {
          ++r;
        }
        EXPECT_EQ(g.root_level(), r) << g.ToString();
        EXPECT_EQ(g.level_count(), r + 1);
        // The root covers the volume; its children level alone would not (unless R == 0).
        EXPECT_TRUE(g.NodeBoxLevel0(g.RootKey()).ContainsBox(g.ValidExtent(0)));
        EXPECT_EQ(g.NodesPerAxis(g.root_level()), 1);
        EXPECT_EQ(g.NodesPerAxis(0), int64_t{1} << r);
        // The root level holds at most one brick of valid voxels per axis.
        const Vec3 top = g.LevelSize(g.root_level());
        for (int a = 0; a < 3; ++a) EXPECT_LE(top[a], brick[a]);
      }
    }
  }
}

TEST(BrickGeometryTest, PaperArbitraryDimensionsExample) {
  // "a volume with original resolution 3865 x 1966 x 2893 would be virtually increased to a
  // 4096^3 volume for a given M = 32 ... a brick resolution of 32 x 16 x 32 results in a virtual
  // volume resolution of 4096 x 2048 x 4096".
  const BrickGeometry cubic = Make({3865, 1966, 2893}, {32, 32, 32});
  EXPECT_EQ(cubic.root_level(), 7);
  EXPECT_EQ(cubic.NodeBoxLevel0(cubic.RootKey()), (Box{{0, 0, 0}, {4096, 4096, 4096}}));
  const BrickGeometry flat = Make({3865, 1966, 2893}, {32, 16, 32});
  EXPECT_EQ(flat.root_level(), 7);
  EXPECT_EQ(flat.NodeBoxLevel0(flat.RootKey()), (Box{{0, 0, 0}, {4096, 2048, 4096}}));
}

TEST(BrickGeometryTest, LevelSizesMatchVoxelEnumeration) {
  for (const BrickGeometry& g : SmallGeometries()) {
    SCOPED_TRACE(g.ToString());
    const std::vector<std::set<Vec3>> valid = BruteForceValidSets(g, g.level_count());
    for (int l = 0; l < g.level_count(); ++l) {
      // The valid voxels of each level form exactly the box [0, LevelSize).
      EXPECT_EQ(BoundingBox(valid[l]), g.ValidExtent(l)) << "level " << l;
      EXPECT_EQ(g.ValidExtent(l).VoxelCount(), valid[l].size()) << "level " << l;
      EXPECT_EQ(g.ValidExtent(l).lo, (Vec3{0, 0, 0}));
      EXPECT_EQ(g.ValidExtent(l).hi, g.LevelSize(l));
    }
  }
}

TEST(BrickGeometryTest, NodeBoxesValidBoxesAndVirtualNodesMatchEnumeration) {
  for (const BrickGeometry& g : SmallGeometries()) {
    SCOPED_TRACE(g.ToString());
    const std::vector<std::set<Vec3>> valid_sets = BruteForceValidSets(g, g.level_count());
    for (int l = 0; l < g.level_count(); ++l) {
      const Box grid = g.NodeGrid(l);
      // The extended level (every node's interior) plus a one-voxel margin for aprons.
      const Box extended{{0, 0, 0},
                         {grid.hi[0] * g.brick_size()[0], grid.hi[1] * g.brick_size()[1],
                          grid.hi[2] * g.brick_size()[2]}};
      const DenseSet valid(extended.Dilate(1), valid_sets[l]);
      // Every voxel of the extended level is owned by exactly one node interior.
      DenseSet owners(extended, {});
      ForEachVoxel(grid, [&](const Vec3& n) {
        ForEachVoxel(g.NodeBox({l, n}), [&](const Vec3& p) { ++owners.at(p); });
      });
      ForEachVoxel(extended, [&](const Vec3& p) {
        ASSERT_EQ(owners.at(p), 1)
            << "level " << l << " voxel " << p[0] << "," << p[1] << "," << p[2];
      });
      const Box non_virtual = g.NonVirtualNodes(l);
      EXPECT_TRUE(grid.ContainsBox(non_virtual));
      // Nodes more than an apron away from every valid voxel need no voxel walk: brute force
      // would find no valid voxel in them. (This keeps the brick-size-2 cases fast: their
      // virtual extension is mostly such nodes.)
      const Box near_valid = BoundingBox(valid_sets[l]).Dilate(1);
      ForEachVoxel(grid, [&](const Vec3& n) {
        const NodeKey key{l, n};
        ASSERT_TRUE(g.IsValidKey(key));
        EXPECT_EQ(g.NodeBox(key).VoxelCount(),
                  static_cast<uint64_t>(g.brick_size()[0] * g.brick_size()[1] * g.brick_size()[2]));
        EXPECT_EQ(g.NodeBox(key).lo, (Vec3{n[0] * g.brick_size()[0], n[1] * g.brick_size()[1],
                                           n[2] * g.brick_size()[2]}));
        // The stored box is the interior plus a one-voxel apron.
        EXPECT_EQ(g.StoredBox(key).VoxelCount(), g.brick_voxels());
        EXPECT_EQ(g.StoredBox(key), g.NodeBox(key).Dilate(1));
        EXPECT_EQ(g.NodeBoxLevel0(key), RefineBox(g.NodeBox(key), l));
        if (!g.StoredBox(key).Intersects(near_valid)) {
          EXPECT_TRUE(g.IsVirtual(key)) << key.ToString();
          EXPECT_TRUE(g.ValidBox(key).empty()) << key.ToString();
          EXPECT_TRUE(g.StoredValidBox(key).empty()) << key.ToString();
          EXPECT_FALSE(non_virtual.Contains(n)) << key.ToString();
          return;
        }
        // ValidBox is exactly the valid voxels of the interior, StoredValidBox of the stored box.
        uint64_t valid_count = 0, mismatches = 0;
        ForEachVoxel(g.NodeBox(key), [&](const Vec3& p) {
          mismatches += g.ValidBox(key).Contains(p) != (valid.at(p) == 1);
          mismatches += !(g.NodeContaining(l, p) == key);
          valid_count += valid.at(p);
        });
        ForEachVoxel(g.StoredBox(key), [&](const Vec3& p) {
          mismatches += g.StoredValidBox(key).Contains(p) != (valid.at(p) == 1);
        });
        EXPECT_EQ(mismatches, 0u) << key.ToString();
        EXPECT_EQ(g.ValidBox(key).VoxelCount(), valid_count) << key.ToString();
        EXPECT_EQ(g.IsVirtual(key), valid_count == 0) << key.ToString();
        EXPECT_EQ(non_virtual.Contains(n), !g.IsVirtual(key)) << key.ToString();
      });
      // Keys outside the grid or the levels are invalid.
      EXPECT_FALSE(g.IsValidKey({l, {grid.hi[0], 0, 0}}));
      EXPECT_FALSE(g.IsValidKey({l, {0, -1, 0}}));
      EXPECT_FALSE(g.IsValidKey({l, {0, 0, grid.hi[2]}}));
    }
    EXPECT_FALSE(g.IsValidKey({-1, {0, 0, 0}}));
    EXPECT_FALSE(g.IsValidKey({g.root_level() + 1, {0, 0, 0}}));
    // The root is never virtual: the volume has at least one voxel.
    EXPECT_FALSE(g.IsVirtual(g.RootKey()));
  }
}

TEST(BrickGeometryTest, ChildrenPartitionTheirParent) {
  // Octant bits: 1 = +x, 2 = +y, 4 = +z.
  EXPECT_EQ(ChildKey({3, {1, 2, 3}}, 0), (NodeKey{2, {2, 4, 6}}));
  EXPECT_EQ(ChildKey({3, {1, 2, 3}}, 1), (NodeKey{2, {3, 4, 6}}));
  EXPECT_EQ(ChildKey({3, {1, 2, 3}}, 2), (NodeKey{2, {2, 5, 6}}));
  EXPECT_EQ(ChildKey({3, {1, 2, 3}}, 4), (NodeKey{2, {2, 4, 7}}));
  EXPECT_EQ(ChildKey({3, {1, 2, 3}}, 7), (NodeKey{2, {3, 5, 7}}));
  EXPECT_EQ(NodeKey({2, {3, 5, 7}}).ToString(), "L2(3,5,7)");
  for (const BrickGeometry& g : SmallGeometries()) {
    SCOPED_TRACE(g.ToString());
    for (int l = 1; l < g.level_count(); ++l) {
      ForEachVoxel(g.NodeGrid(l), [&](const Vec3& n) {
        const NodeKey parent{l, n};
        const Box refined = RefineBox(g.NodeBox(parent));
        uint64_t covered = 0;
        bool any_real_child = false;
        for (int o = 0; o < 8; ++o) {
          const NodeKey child = ChildKey(parent, o);
          ASSERT_TRUE(g.IsValidKey(child));
          EXPECT_EQ(ParentKey(child), parent);
          EXPECT_EQ(OctantOf(child), o);
          // The children's interiors are disjoint, lie in the refined parent and add up to it:
          // they tile it exactly.
          EXPECT_TRUE(refined.ContainsBox(g.NodeBox(child)));
          for (int other = 0; other < o; ++other) {
            EXPECT_FALSE(g.NodeBox(child).Intersects(g.NodeBox(ChildKey(parent, other))));
          }
          covered += g.NodeBox(child).VoxelCount();
          EXPECT_TRUE(g.NodeBoxLevel0(parent).ContainsBox(g.NodeBoxLevel0(child)));
          // Even brick sizes: the 2x2x2 groups of a child's interior never straddle its border.
          EXPECT_EQ(RefineBox(CoarsenBox(g.NodeBox(child))), g.NodeBox(child));
          // A child's valid voxels have their parents among the parent's valid voxels.
          EXPECT_TRUE(g.ValidBox(parent).ContainsBox(CoarsenBox(g.ValidBox(child))));
          any_real_child |= !g.IsVirtual(child);
        }
        EXPECT_EQ(covered, refined.VoxelCount());
        // A virtual parent has only virtual children; a non-virtual one has a non-virtual child.
        EXPECT_EQ(any_real_child, !g.IsVirtual(parent)) << parent.ToString();
      });
    }
  }
}

TEST(BrickGeometryTest, NodesTouchingABoxMatchBruteForce) {
  std::mt19937 rng(11);
  for (const BrickGeometry& g : SmallGeometries()) {
    SCOPED_TRACE(g.ToString());
    for (int l = 0; l < g.level_count(); ++l) {
      const Box grid = g.NodeGrid(l);
      // Fewer boxes on the huge (mostly virtual) grids of brick size 2, to stay fast.
      const int trials = grid.VoxelCount() > 4096 ? 4 : 40;
      for (int trial = 0; trial < trials; ++trial) {
        Box box;
        for (int a = 0; a < 3; ++a) {
          const int64_t extent = grid.hi[a] * g.brick_size()[a];
          box.lo[a] = std::uniform_int_distribution<int64_t>(-3, extent + 2)(rng);
          box.hi[a] = box.lo[a] + std::uniform_int_distribution<int64_t>(0, extent / 2 + 3)(rng);
        }
        // Brute force over every node of the grid (Box::Intersect is checked voxel by voxel in
        // BoxTest.IntersectMatchesVoxelEnumeration).
        std::set<Vec3> interior_hits, stored_hits;
        ForEachVoxel(grid, [&](const Vec3& n) {
          if (g.NodeBox({l, n}).Intersects(box)) interior_hits.insert(n);
          if (g.StoredBox({l, n}).Intersects(box)) stored_hits.insert(n);
        });
        const Box interior = g.NodesIntersecting(l, box);
        const Box stored = g.NodesStoringAny(l, box);
        EXPECT_EQ(interior.VoxelCount(), interior_hits.size()) << box.ToString();
        EXPECT_EQ(stored.VoxelCount(), stored_hits.size()) << box.ToString();
        if (!interior_hits.empty()) {
          EXPECT_EQ(interior, BoundingBox(interior_hits));
        }
        if (!stored_hits.empty()) {
          EXPECT_EQ(stored, BoundingBox(stored_hits));
        }
        EXPECT_TRUE(stored.ContainsBox(interior));
      }
      // The whole valid extent touches exactly the non-virtual nodes' interiors.
      EXPECT_EQ(g.NodesIntersecting(l, g.ValidExtent(l)), g.NonVirtualNodes(l));
      EXPECT_TRUE(g.NodesIntersecting(l, Box{{2, 2, 2}, {2, 3, 3}}).empty());
      EXPECT_TRUE(g.NodesStoringAny(l, Box{{2, 2, 2}, {2, 3, 3}}).empty());
    }
  }
}

TEST(BrickGeometryTest, DirtyRegionPropagationMatchesParentSets) {
  // The octree propagates a dirty box up by CoarsenBox; clipped to the valid extent this must be
  // exactly the set of valid parents of the dirty valid voxels.
  std::mt19937 rng(3);
  const BrickGeometry g = Make({67, 33, 5}, {4, 6, 2});
  for (int trial = 0; trial < 50; ++trial) {
    Box box;
    for (int a = 0; a < 3; ++a) {
      box.lo[a] = std::uniform_int_distribution<int64_t>(0, g.volume_size()[a] - 1)(rng);
      box.hi[a] = std::uniform_int_distribution<int64_t>(box.lo[a] + 1, g.volume_size()[a])(rng);
    }
    std::set<Vec3> dirty;
    ForEachVoxel(box, [&](const Vec3& p) { dirty.insert(p); });
    Box level_box = box;
    for (int l = 1; l < g.level_count(); ++l) {
      std::set<Vec3> parents;
      for (const Vec3& p : dirty) parents.insert({p[0] / 2, p[1] / 2, p[2] / 2});
      dirty = parents;
      level_box = CoarsenBox(level_box).Intersect(g.ValidExtent(l));
      EXPECT_EQ(level_box, BoundingBox(dirty));
      EXPECT_EQ(level_box.VoxelCount(), dirty.size());
    }
  }
}

TEST(BrickGeometryTest, StoredOffsetsAreADenseChannelInterleavedLayout) {
  for (const BrickGeometry& g :
       {Make({67, 33, 5}, {64, 32, 16}, 3, 2), Make({67, 33, 5}, {2, 2, 2}, 1, 1),
        Make({9, 9, 9}, {4, 6, 2}, 4, 1)}) {
    SCOPED_TRACE(g.ToString());
    const Vec3 s = g.stored_size();
    EXPECT_EQ(s, (Vec3{g.brick_size()[0] + 2, g.brick_size()[1] + 2, g.brick_size()[2] + 2}));
    EXPECT_EQ(g.brick_voxels(), static_cast<uint64_t>(s[0] * s[1] * s[2]));
    EXPECT_EQ(g.brick_samples(), g.brick_voxels() * g.channels());
    EXPECT_EQ(g.brick_bytes(), g.brick_samples() * g.bytes_per_sample());
    // Check one interior and one boundary node at every level.
    for (int l = 0; l < g.level_count(); ++l) {
      const Box grid = g.NodeGrid(l);
      for (const NodeKey& key :
           {NodeKey{l, {0, 0, 0}}, NodeKey{l, {grid.hi[0] - 1, grid.hi[1] - 1, grid.hi[2] - 1}}}) {
        std::vector<bool> seen(g.brick_samples(), false);
        const Box stored = g.StoredBox(key);
        ForEachVoxel(stored, [&](const Vec3& p) {
          const int64_t x = p[0] - stored.lo[0], y = p[1] - stored.lo[1], z = p[2] - stored.lo[2];
          for (int c = 0; c < g.channels(); ++c) {
            const uint64_t expected =
                static_cast<uint64_t>(((z * s[1] + y) * s[0] + x) * g.channels() + c);
            const uint64_t offset = g.StoredSampleOffset(key, p, c);
            ASSERT_EQ(offset, expected) << key.ToString() << " " << x << "," << y << "," << z;
            EXPECT_EQ(g.LocalSampleOffset({x, y, z}, c), expected);
            EXPECT_EQ(g.StoredByteOffset(key, p, c), expected * g.bytes_per_sample());
            ASSERT_LT(offset, g.brick_samples());
            EXPECT_FALSE(seen[offset]);
            seen[offset] = true;
          }
        });
        EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](bool b) { return b; }));
        // The first interior voxel sits one apron voxel in on every axis.
        EXPECT_EQ(g.StoredSampleOffset(key, g.NodeBox(key).lo, 0),
                  static_cast<uint64_t>(((1 * s[1] + 1) * s[0] + 1) * g.channels()));
      }
    }
  }
  // Hand-worked: brick 64x32x16 => stored 66x34x18, 3 channels, 2 bytes.
  const BrickGeometry g = Make({67, 33, 5}, {64, 32, 16}, 3, 2);
  EXPECT_EQ(g.brick_bytes(), 66u * 34u * 18u * 3u * 2u);
  EXPECT_EQ(g.LocalSampleOffset({65, 33, 17}, 2), 66u * 34u * 18u * 3u - 1u);
}

TEST(BrickGeometryTest, NodeKeyHashSeparatesAllNodes) {
  const BrickGeometry g = Make({33, 17, 9}, {2, 2, 2});
  std::unordered_set<size_t> hashes;
  std::unordered_set<NodeKey, NodeKeyHash> keys;
  uint64_t count = 0;
  for (int l = 0; l < g.level_count(); ++l) {
    ForEachVoxel(g.NodeGrid(l), [&](const Vec3& n) {
      hashes.insert(NodeKeyHash()({l, n}));
      keys.insert({l, n});
      ++count;
    });
  }
  EXPECT_EQ(count, g.MaxNodeCount());
  EXPECT_EQ(keys.size(), count);
  EXPECT_EQ(hashes.size(), count) << "hash collisions between distinct nodes";
}

TEST(BrickGeometryTest, LargestVolumeIsExactAndOverflowFree) {
  constexpr int64_t kN = 65536;
  {
    const BrickGeometry g = Make({kN, kN, kN}, {64, 64, 64}, kMaxChannels, 2);
    EXPECT_EQ(g.root_level(), 10);  // 64 * 2^10 = 65536.
    EXPECT_EQ(g.ValidExtent(0).VoxelCount(), uint64_t{1} << 48);
    EXPECT_EQ(g.NodeBoxLevel0(g.RootKey()), (Box{{0, 0, 0}, {kN, kN, kN}}));
    // Complete tree: (8^11 - 1) / 7 nodes.
    EXPECT_EQ(g.MaxNodeCount(), ((uint64_t{1} << 33) - 1) / 7);
    EXPECT_EQ(g.LevelSize(10), (Vec3{64, 64, 64}));
    EXPECT_EQ(g.NonVirtualNodes(0), (Box{{0, 0, 0}, {1024, 1024, 1024}}));
    // The far corner voxel lives in the last leaf, at the last interior position.
    const NodeKey last = g.NodeContaining(0, {kN - 1, kN - 1, kN - 1});
    EXPECT_EQ(last, (NodeKey{0, {1023, 1023, 1023}}));
    EXPECT_EQ(g.StoredBox(last), (Box{{kN - 65, kN - 65, kN - 65}, {kN + 1, kN + 1, kN + 1}}));
    EXPECT_EQ(g.ValidBox(last), (Box{{kN - 64, kN - 64, kN - 64}, {kN, kN, kN}}));
    EXPECT_EQ(g.StoredValidBox(last), (Box{{kN - 65, kN - 65, kN - 65}, {kN, kN, kN}}));
    EXPECT_EQ(g.StoredSampleOffset(last, {kN, kN, kN}, kMaxChannels - 1), g.brick_samples() - 1);
    EXPECT_EQ(g.NodesStoringAny(0, g.ValidExtent(0)), g.NodeGrid(0));
    EXPECT_EQ(g.NodesStoringAny(0, Box{{kN - 1, 0, 0}, {kN, 1, 1}}),
              (Box{{1023, 0, 0}, {1024, 1, 1}}));
    EXPECT_EQ(g.NodesStoringAny(0, Box{{64, 64, 64}, {65, 65, 65}}), (Box{{0, 0, 0}, {2, 2, 2}}));
  }
  {
    // The deepest possible tree: brick size 2 gives 16 levels and ~4e13 nodes.
    const BrickGeometry g = Make({kN, kN, kN}, {2, 2, 2});
    EXPECT_EQ(g.root_level(), 15);
    uint64_t nodes = 0;
    for (int l = 0; l <= 15; ++l) nodes += uint64_t{1} << (3 * (15 - l));
    EXPECT_EQ(g.MaxNodeCount(), nodes);
    EXPECT_LT(g.MaxNodeCount(), uint64_t{1} << 46);
    EXPECT_EQ(g.NodesPerAxis(0), 32768);
    for (int l = 0; l <= 15; ++l) EXPECT_EQ(g.LevelSize(l)[0], kN >> l);
    EXPECT_EQ(g.NodeContaining(0, {kN - 1, 0, kN - 2}).index, (Vec3{32767, 0, 32767}));
    EXPECT_EQ(g.NodeBoxLevel0({15, {0, 0, 0}}), (Box{{0, 0, 0}, {kN, kN, kN}}));
    EXPECT_EQ(g.NodeBoxLevel0({0, {32767, 32767, 32767}}),
              (Box{{kN - 2, kN - 2, kN - 2}, {kN, kN, kN}}));
  }
  {
    // A line: 65536x1x1 with brick 2 extends virtually in y and z; only one node row is real.
    const BrickGeometry g = Make({kN, 1, 1}, {2, 2, 2});
    EXPECT_EQ(g.root_level(), 15);
    EXPECT_EQ(g.NonVirtualNodes(0), (Box{{0, 0, 0}, {32768, 1, 1}}));
    EXPECT_EQ(g.NonVirtualNodes(14), (Box{{0, 0, 0}, {2, 1, 1}}));
    EXPECT_TRUE(g.IsVirtual({0, {0, 1, 0}}));
    EXPECT_FALSE(g.IsVirtual({0, {32767, 0, 0}}));
    EXPECT_EQ(g.LevelSize(15), (Vec3{2, 1, 1}));
  }
  {
    // Anisotropic extreme: small bricks on the long axis force R = 15, so the root's level-0 box
    // is 1024 * 2^15 = 2^25 voxels wide in x and y; its voxel count (2^66) saturates.
    const BrickGeometry g = Make({1, 1, kN}, {1024, 1024, 2});
    EXPECT_EQ(g.root_level(), 15);
    const int64_t wide = int64_t{1024} << 15;
    EXPECT_EQ(g.NodeBoxLevel0(g.RootKey()), (Box{{0, 0, 0}, {wide, wide, kN}}));
    EXPECT_EQ(g.NodeBoxLevel0(g.RootKey()).VoxelCount(), UINT64_MAX);
    EXPECT_EQ((Box{{0, 0, 0}, {wide, wide, 1}}).VoxelCount(), uint64_t{1} << 50);
    EXPECT_EQ(g.ValidBox(g.RootKey()), (Box{{0, 0, 0}, {1, 1, 2}}));
    EXPECT_EQ(g.NonVirtualNodes(0), (Box{{0, 0, 0}, {1, 1, 32768}}));
    EXPECT_EQ(g.NodesStoringAny(0, g.ValidExtent(0)), (Box{{0, 0, 0}, {1, 1, 32768}}));
    EXPECT_EQ(g.StoredSampleOffset({0, {0, 0, 32767}}, {1024, 1024, kN}, 0), g.brick_samples() - 1);
  }
  {
    // An uneven extreme: 65536 x 3 x 65535 with the largest brick on one axis.
    const BrickGeometry g = Make({kN, 3, kN - 1}, {1024, 2, 64});
    EXPECT_EQ(g.root_level(), 10);  // z: 64 * 2^10 = 65536 >= 65535.
    EXPECT_EQ(g.LevelSize(10), (Vec3{64, 1, 64}));
    EXPECT_EQ(g.NonVirtualNodes(0), (Box{{0, 0, 0}, {64, 2, 1024}}));
    EXPECT_EQ(g.ValidBox({0, {63, 1, 1023}}), (Box{{64512, 2, 65472}, {kN, 3, kN - 1}}));
  }
}

}  // namespace
}  // namespace octoscope::octree

namespace octoscope::octree {
namespace {

TEST(AutoBrickSizeTest, PicksTheLeastPaddingWithinSixtyFour) {
  // Multiples of 64 keep 64.
  EXPECT_EQ(AutoBrickSize({1024, 1024, 512}), (Vec3{64, 64, 64}));
  // Thin stacks get shallow bricks: a single plane 2, a 30-plane stack 30.
  EXPECT_EQ(AutoBrickSize({502, 623, 1})[2], 2);
  EXPECT_EQ(AutoBrickSize({333, 257, 30})[2], 30);
  for (const Vec3& size : {Vec3{133, 130, 45}, Vec3{667, 510, 30}, Vec3{1000, 77, 3},
                           Vec3{65536, 65536, 65536}, Vec3{1, 1, 1}}) {
    const Vec3 b = AutoBrickSize(size);
    const uint64_t chosen = CompleteTreeStoredVoxels(size, b);
    ASSERT_GT(chosen, 0u);
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(b[a] % 2, 0);
      EXPECT_GE(b[a], 2);
      EXPECT_LE(b[a], 64);
    }
    // Never worse than the old fixed 64^3 bricks.
    EXPECT_LE(chosen, CompleteTreeStoredVoxels(size, kDefaultBrickSize)) << size[0];
  }
  // The thin crop: padding roughly halves or better.
  EXPECT_LT(CompleteTreeStoredVoxels({333, 257, 30}, AutoBrickSize({333, 257, 30})) * 2,
            CompleteTreeStoredVoxels({333, 257, 30}, kDefaultBrickSize));
}

}  // namespace
}  // namespace octoscope::octree
