// Octree construction tests. Every expectation is computed independently from the source voxels
// (tests/octree/octree_reference.h) or written out by hand (the paper's Fig. 3).
#include "octree/octree.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <random>
#include <span>
#include <sstream>
#include <string>
#include <vector>

#include "change_mirror.h"
#include "octree_reference.h"

namespace octoscope::octree {
namespace {

using testing::BrickSample;
using testing::BuildReference;
using testing::ChangeMirror;
using testing::DumpTree;
using testing::ExpectMirrors;
using testing::ExpectSameTree;
using testing::InsertBox;
using testing::MakePatternVolume;
using testing::Params;
using testing::ReferencePyramid;
using testing::ReferenceStats;
using testing::SourceVolume;
using testing::TreeFixture;
using testing::ZSlabs;

uint16_t RoundHalfUp(double v) { return static_cast<uint16_t>(std::floor(v + 0.5)); }

// --- Insertion orders / block shapes (each voxel of every channel exactly once). ---

std::vector<Box> XSlices(const Vec3& size) {
  std::vector<Box> out;
  for (int64_t x = 0; x < size[0]; ++x) out.push_back(Box{{x, 0, 0}, {x + 1, size[1], size[2]}});
  return out;
}

// A random partition into unaligned blocks: cut each axis at random positions.
std::vector<Box> RandomBlocks(const Vec3& size, uint32_t seed) {
  std::mt19937 rng(seed);
  std::array<std::vector<int64_t>, 3> cuts;
  for (int a = 0; a < 3; ++a) {
    cuts[a] = {0, size[a]};
    for (int i = 0; i < 3; ++i) cuts[a].push_back(static_cast<int64_t>(rng() % size[a]));
    std::sort(cuts[a].begin(), cuts[a].end());
    cuts[a].erase(std::unique(cuts[a].begin(), cuts[a].end()), cuts[a].end());
  }
  std::vector<Box> out;
  for (size_t k = 0; k + 1 < cuts[2].size(); ++k)
    for (size_t j = 0; j + 1 < cuts[1].size(); ++j)
      for (size_t i = 0; i + 1 < cuts[0].size(); ++i)
        out.push_back(Box{{cuts[0][i], cuts[1][j], cuts[2][k]},
                          {cuts[0][i + 1], cuts[1][j + 1], cuts[2][k + 1]}});
  std::shuffle(out.begin(), out.end(), rng);
  return out;
}

void InsertAll(Octree& tree, const SourceVolume& src, const std::vector<Box>& boxes) {
  for (const Box& b : boxes)
    for (int c = 0; c < src.channels; ++c) InsertBox(tree, src, c, b);
}

// --- The reference check of a COMPLETE tree. ---
// Structure: a node has a brick iff its own level range > tolerance in some channel; children iff
// its level-0 region's range > tolerance in some channel (and it is not a leaf / virtual).
// Stats: exactly the reference's. Bricks: interior = reference level; apron = neighbours'
// representation (their reference voxels where they have a brick, else the rounded average of the
// deepest existing node), virtual voxels = background.
void VerifyCompleteTree(const Octree& tree, const SourceVolume& src) {
  const BrickGeometry& g = tree.geometry();
  std::vector<uint16_t> bg(src.channels);
  for (int c = 0; c < src.channels; ++c) bg[c] = tree.background(c);
  const ReferencePyramid ref = BuildReference(src, g.level_count(), bg);

  // The value a level-L voxel shows in the tree's current structure.
  auto represented = [&](int level, const Vec3& p, int c) -> uint16_t {
    if (!ref.Valid(level, p)) return bg[c];
    NodeKey key = g.RootKey();
    for (;;) {
      std::optional<NodeSnapshot> n = tree.GetNode(key);
      EXPECT_TRUE(n.has_value());
      if (!n) return 0;
      if (key.level == level)
        return n->has_brick() ? ref.at(level, c, p) : RoundHalfUp(n->channels[c].avg);
      if (!n->has_children()) return RoundHalfUp(n->channels[c].avg);
      const int shift = key.level - 1 - level;
      int octant = 0;
      for (int a = 0; a < 3; ++a)
        octant |= static_cast<int>(((p[a] / g.brick_size()[a]) >> shift) & 1) << a;
      key = ChildKey(key, octant);
    }
  };

  std::vector<NodeKey> stack{g.RootKey()};
  int checked = 0;
  while (!stack.empty()) {
    const NodeKey key = stack.back();
    stack.pop_back();
    std::optional<NodeSnapshot> node = tree.GetNode(key);
    ASSERT_TRUE(node.has_value()) << key.ToString();
    ++checked;
    const bool is_virtual = g.IsVirtual(key);
    ASSERT_EQ(node->is_virtual, is_virtual) << key.ToString();
    if (is_virtual) {
      EXPECT_FALSE(node->has_brick());
      EXPECT_FALSE(node->has_children());
      for (int c = 0; c < src.channels; ++c) {
        EXPECT_EQ(node->channels[c].min, bg[c]);
        EXPECT_EQ(node->channels[c].avg, bg[c]);
      }
      continue;
    }
    EXPECT_TRUE(node->complete) << key.ToString();
    const Box valid = g.ValidBox(key);
    const Box region0 = g.NodeBoxLevel0(key).Intersect(g.ValidExtent(0));
    bool own_homogeneous = true, sub_homogeneous = true;
    for (int c = 0; c < src.channels; ++c) {
      const auto own = ReferenceStats(ref, key.level, c, valid);
      const auto sub = ReferenceStats(ref, 0, c, region0);
      const ChannelSummary& s = node->channels[c];
      EXPECT_EQ(s.min, own.min) << key.ToString() << " c" << c;
      EXPECT_EQ(s.max, own.max) << key.ToString() << " c" << c;
      EXPECT_EQ(s.avg, own.avg) << key.ToString() << " c" << c;
      EXPECT_EQ(s.subtree_min, sub.min) << key.ToString() << " c" << c;
      EXPECT_EQ(s.subtree_max, sub.max) << key.ToString() << " c" << c;
      own_homogeneous = own_homogeneous && own.max - own.min <= tree.tolerance(c);
      sub_homogeneous = sub_homogeneous && sub.max - sub.min <= tree.tolerance(c);
    }
    ASSERT_EQ(node->has_brick(), !own_homogeneous) << key.ToString();
    ASSERT_EQ(node->has_children(), key.level > 0 && !sub_homogeneous) << key.ToString();
    if (node->has_brick()) {
      std::vector<std::byte> brick(g.brick_bytes());
      ASSERT_TRUE(tree.ReadBrick(node->id, brick).ok());
      const Box stored = g.StoredBox(key);
      for (int c = 0; c < src.channels; ++c)
        for (int64_t z = stored.lo[2]; z < stored.hi[2]; ++z)
          for (int64_t y = stored.lo[1]; y < stored.hi[1]; ++y)
            for (int64_t x = stored.lo[0]; x < stored.hi[0]; ++x) {
              const Vec3 p{x, y, z};
              const uint16_t expected = g.NodeBox(key).Contains(p) && ref.Valid(key.level, p)
                                            ? ref.at(key.level, c, p)
                                            : represented(key.level, p, c);
              ASSERT_EQ(BrickSample(g, key, brick, p, c), expected)
                  << key.ToString() << " voxel " << x << "," << y << "," << z << " c" << c;
            }
    }
    if (node->has_children())
      for (int octant = 0; octant < 8; ++octant) stack.push_back(ChildKey(key, octant));
  }
  EXPECT_GT(checked, 0);
}

// --------------------------------------------------------------------------------------------

TEST(OctreeTest, NewTreeIsARootStoringTheBackground) {
  OctreeOptions options;
  options.background = {7, 300};
  TreeFixture f = TreeFixture::Make(Params({20, 10, 6}, {4, 4, 2}, 2, 2), options);
  ASSERT_TRUE(f.tree);
  auto root = f.tree->GetNode(f.tree->geometry().RootKey());
  ASSERT_TRUE(root.has_value());
  EXPECT_EQ(root->id, 0u);
  EXPECT_FALSE(root->has_children());
  EXPECT_FALSE(root->has_brick());
  EXPECT_FALSE(root->complete);
  EXPECT_EQ(root->channels[0], (ChannelSummary{7, 7, 7, 7, 7.0}));
  EXPECT_EQ(root->channels[1], (ChannelSummary{300, 300, 300, 300, 300.0}));
  EXPECT_EQ(f.tree->stats(), (OctreeStats{1, 0, 1, 0}));
  // The root was created before anyone subscribed: it is in the tree, not in the change log.
  ChangeSubscription changes = f.tree->SubscribeChanges();
  const ChangeBatch batch = changes.Poll();
  EXPECT_FALSE(batch.resync);
  EXPECT_TRUE(batch.events.empty());
}

// The paper's Fig. 3 in 1-D: a 16-voxel line, bricks of 4 (x; y and z are 2 and virtual beyond
// the single valid row), threshold one, four blocks. Expected values worked out by hand (see the
// test's comments); parents are means of 2 valid children (y/z children are virtual).
TEST(OctreeTest, PaperFigure3WalkThrough) {
  OctreeOptions options;
  options.brick_size = {4, 2, 2};
  options.homogeneity_tolerance = {1};
  TreeFixture f = TreeFixture::Make(Params({16, 1, 1}, {4, 2, 2}, 1, 1), options);
  ASSERT_TRUE(f.tree);
  Octree& tree = *f.tree;
  const BrickGeometry& g = tree.geometry();
  ASSERT_EQ(g.root_level(), 2);

  auto insert = [&](int64_t x0, std::vector<uint8_t> values) {
    std::vector<std::byte> data(values.size());
    for (size_t i = 0; i < values.size(); ++i) data[i] = static_cast<std::byte>(values[i]);
    const Box box{{x0, 0, 0}, {x0 + static_cast<int64_t>(values.size()), 1, 1}};
    Status st = tree.Insert(0, box, data);
    ASSERT_TRUE(st.ok()) << st.ToString();
  };
  auto key = [](int level, int64_t x) { return NodeKey{level, {x, 0, 0}}; };
  // Checks a node: brick interior row (nullopt = no brick), min, max, avg.
  auto expect_node = [&](const NodeKey& k, std::optional<std::vector<int>> row, int min, int max,
                         double avg, const char* step) {
    SCOPED_TRACE(std::string(step) + " " + k.ToString());
    auto n = tree.GetNode(k);
    ASSERT_TRUE(n.has_value());
    EXPECT_EQ(n->channels[0].min, min);
    EXPECT_EQ(n->channels[0].max, max);
    EXPECT_DOUBLE_EQ(n->channels[0].avg, avg);
    ASSERT_EQ(n->has_brick(), row.has_value());
    if (!row) return;
    std::vector<std::byte> brick(g.brick_bytes());
    ASSERT_TRUE(tree.ReadBrick(n->id, brick).ok());
    for (int i = 0; i < 4; ++i) {
      EXPECT_EQ(BrickSample(g, k, brick, {k.index[0] * 4 + i, 0, 0}, 0), (*row)[i]) << "x " << i;
    }
  };

  // Step 1: [1,5,2] at x = 0. Level 0: 1 5 2 0 | 0 0 0 0 | ...; level 1: 3 1 0 0 | 0 0 0 0;
  // root: 2 0 0 0. The leftmost path gets nodes and bricks, nothing is complete.
  insert(0, {1, 5, 2});
  expect_node(key(0, 0), std::vector<int>{1, 5, 2, 0}, 0, 5, 2.0, "step 1");
  expect_node(key(0, 1), std::nullopt, 0, 0, 0.0, "step 1");
  expect_node(key(1, 0), std::vector<int>{3, 1, 0, 0}, 0, 3, 1.0, "step 1");
  expect_node(key(1, 1), std::nullopt, 0, 0, 0.0, "step 1");
  expect_node(key(2, 0), std::vector<int>{2, 0, 0, 0}, 0, 2, 0.5, "step 1");
  EXPECT_FALSE(tree.GetNode(key(0, 2)).has_value());  // The right half has no children yet.
  EXPECT_EQ(tree.stats().bricks, 3u);

  // Step 2: [3,3,2,2] at x = 6 (not coherent with step 1). Level 0: 1 5 2 0 | 0 0 3 3 |
  // 2 2 0 0 | 0 0 0 0; level 1: 3 1 0 3 | 2 0 0 0; root: 2 2 1 0.
  insert(6, {3, 3, 2, 2});
  expect_node(key(0, 1), std::vector<int>{0, 0, 3, 3}, 0, 3, 1.5, "step 2");
  expect_node(key(0, 2), std::vector<int>{2, 2, 0, 0}, 0, 2, 1.0, "step 2");
  expect_node(key(0, 3), std::nullopt, 0, 0, 0.0, "step 2");
  expect_node(key(1, 0), std::vector<int>{3, 1, 0, 3}, 0, 3, 1.75, "step 2");
  expect_node(key(1, 1), std::vector<int>{2, 0, 0, 0}, 0, 2, 0.5, "step 2");
  expect_node(key(2, 0), std::vector<int>{2, 2, 1, 0}, 0, 2, 1.25, "step 2");
  EXPECT_EQ(tree.stats().bricks, 6u);

  // Step 3: [4,3,3] at x = 3: the first optimisation. Leaf 1 = 3 3 3 3 and level-1 node 0 =
  // 3 3 3 3 are complete and homogeneous: their bricks go, their average 3 stays. The left
  // subtree stays: the leftmost leaf spans 1..5.
  insert(3, {4, 3, 3});
  expect_node(key(0, 0), std::vector<int>{1, 5, 2, 4}, 1, 5, 3.0, "step 3");
  expect_node(key(0, 1), std::nullopt, 3, 3, 3.0, "step 3");
  expect_node(key(1, 0), std::nullopt, 3, 3, 3.0, "step 3");
  expect_node(key(2, 0), std::vector<int>{3, 3, 1, 0}, 0, 3, 1.75, "step 3");
  {
    auto left = tree.GetNode(key(1, 0));
    ASSERT_TRUE(left.has_value());
    EXPECT_TRUE(left->complete);
    EXPECT_TRUE(left->has_children());
    EXPECT_EQ(left->channels[0].subtree_min, 1);
    EXPECT_EQ(left->channels[0].subtree_max, 5);
  }
  EXPECT_EQ(tree.stats().bricks, 4u);  // Leaf 0, leaf 2, level-1 node 1, root.

  // Step 4: the rest, [4,4,2,4,3,3] at x = 10. Level 0 right: 2 2 4 4 | 2 4 3 3; level 1 right:
  // 2 4 3 3; root 3 3 3 3: homogeneous, its brick goes, but no subtree can be deleted.
  insert(10, {4, 4, 2, 4, 3, 3});
  expect_node(key(0, 2), std::vector<int>{2, 2, 4, 4}, 2, 4, 3.0, "step 4");
  expect_node(key(0, 3), std::vector<int>{2, 4, 3, 3}, 2, 4, 3.0, "step 4");
  expect_node(key(1, 1), std::vector<int>{2, 4, 3, 3}, 2, 4, 3.0, "step 4");
  expect_node(key(2, 0), std::nullopt, 3, 3, 3.0, "step 4");
  auto root = tree.GetNode(key(2, 0));
  ASSERT_TRUE(root.has_value());
  EXPECT_TRUE(root->complete);
  EXPECT_TRUE(root->has_children());
  EXPECT_EQ(root->channels[0].subtree_min, 1);
  EXPECT_EQ(root->channels[0].subtree_max, 5);
  EXPECT_EQ(tree.stats().bricks, 4u);  // Leaves 0, 2, 3 and level-1 node 1.
  // Aprons: leaf 2's left apron shows leaf 1 (pruned, average 3); leaf 0's right apron shows
  // x = 4 (3); the left apron of leaf 0 is outside the volume (background 0).
  std::vector<std::byte> brick(g.brick_bytes());
  ASSERT_TRUE(tree.ReadBrick(tree.GetNode(key(0, 2))->id, brick).ok());
  EXPECT_EQ(BrickSample(g, key(0, 2), brick, {7, 0, 0}, 0), 3);
  EXPECT_EQ(BrickSample(g, key(0, 2), brick, {12, 0, 0}, 0), 2);
  ASSERT_TRUE(tree.ReadBrick(tree.GetNode(key(0, 0))->id, brick).ok());
  EXPECT_EQ(BrickSample(g, key(0, 0), brick, {4, 0, 0}, 0), 3);
  EXPECT_EQ(BrickSample(g, key(0, 0), brick, {-1, 0, 0}, 0), 0);
  SourceVolume src({16, 1, 1}, 1);
  const std::vector<int> all{1, 5, 2, 4, 3, 3, 3, 3, 2, 2, 4, 4, 2, 4, 3, 3};
  for (int x = 0; x < 16; ++x) src.at(0, x, 0, 0) = static_cast<uint16_t>(all[x]);
  VerifyCompleteTree(tree, src);
}

struct BuildCase {
  Vec3 size;
  Vec3 brick;
  int channels;
  int bps;
  double threshold;
  uint16_t background;
};

class OctreeBuildTest : public ::testing::TestWithParam<BuildCase> {};

// Every insertion order / block shape gives the same tree, and it matches the reference.
TEST_P(OctreeBuildTest, FinalTreeIsIndependentOfOrderAndMatchesReference) {
  const BuildCase& bc = GetParam();
  const SourceVolume src = MakePatternVolume(bc.size, bc.channels, bc.bps, 42);
  OctreeOptions options;
  options.brick_size = bc.brick;
  options.homogeneity_threshold = bc.threshold;
  options.background.assign(bc.channels, bc.background);
  const auto params = Params(bc.size, bc.brick, bc.channels, bc.bps);

  std::vector<std::pair<std::string, std::vector<Box>>> orders;
  orders.push_back({"one shot", {Box{{0, 0, 0}, bc.size}}});
  orders.push_back({"z slabs", ZSlabs(bc.size)});
  auto reversed = ZSlabs(bc.size);
  std::reverse(reversed.begin(), reversed.end());
  orders.push_back({"z slabs reversed", reversed});
  auto shuffled = XSlices(bc.size);
  std::shuffle(shuffled.begin(), shuffled.end(), std::mt19937(7));
  orders.push_back({"shuffled x slices", shuffled});
  orders.push_back({"random blocks", RandomBlocks(bc.size, 11)});

  std::vector<testing::NodeDump> first;
  OctreeStats first_stats;
  for (const auto& [name, boxes] : orders) {
    SCOPED_TRACE(name);
    TreeFixture f = TreeFixture::Make(params, options);
    ASSERT_TRUE(f.tree);
    InsertAll(*f.tree, src, boxes);
    if (name == "one shot") {
      VerifyCompleteTree(*f.tree, src);
      first = DumpTree(*f.tree);
      first_stats = f.tree->stats();
      EXPECT_GT(first_stats.homogeneous_nodes, 0u);
      EXPECT_GT(first_stats.bricks, 0u);
    } else {
      ExpectSameTree(first, DumpTree(*f.tree), name);
      EXPECT_EQ(f.tree->stats(), first_stats);
    }
    if (::testing::Test::HasFailure()) return;
  }
}

INSTANTIATE_TEST_SUITE_P(Shapes, OctreeBuildTest,
                         ::testing::Values(
                             // Odd sizes exercise the virtual extension (67x33x5 as in the spec).
                             BuildCase{{67, 33, 5}, {8, 8, 4}, 2, 2, 0.0, 0},
                             BuildCase{{67, 33, 5}, {8, 8, 4}, 2, 2, 0.05, 0},
                             // uint8, non-zero background, anisotropic bricks, 3 channels.
                             BuildCase{{21, 18, 13}, {4, 6, 2}, 3, 1, 0.0, 200},
                             BuildCase{{21, 18, 13}, {4, 6, 2}, 3, 1, 0.05, 9},
                             BuildCase{{16, 16, 16}, {4, 4, 4}, 1, 2, 0.0, 0}),
                         [](const ::testing::TestParamInfo<BuildCase>& info) {
                           const BuildCase& c = info.param;
                           return std::to_string(c.size[0]) + "x" + std::to_string(c.size[1]) +
                                  "x" + std::to_string(c.size[2]) + "_brick" +
                                  std::to_string(c.brick[0]) + "x" + std::to_string(c.brick[1]) +
                                  "x" + std::to_string(c.brick[2]) + "_" +
                                  std::to_string(c.channels) + "ch_" + std::to_string(8 * c.bps) +
                                  "bit_threshold" +
                                  std::to_string(static_cast<int>(c.threshold * 100)) + "pct_bg" +
                                  std::to_string(c.background);
                         });

// A trilinear sample of level 0 taken from ONE leaf brick (interior + apron) equals the sample
// computed from the source volume, everywhere the 8 neighbours are valid.
TEST(OctreeTest, TrilinearSamplesAcrossBrickBoundariesUseTheApron) {
  const Vec3 size{19, 14, 11};
  SourceVolume src(size, 1);
  std::mt19937 rng(3);
  for (auto& v : src.data[0]) v = static_cast<uint16_t>(rng() % 60000);
  OctreeOptions options;
  options.brick_size = {4, 4, 4};
  TreeFixture f = TreeFixture::Make(Params(size, {4, 4, 4}, 1, 2), options);
  ASSERT_TRUE(f.tree);
  InsertAll(*f.tree, src, RandomBlocks(size, 5));
  const BrickGeometry& g = f.tree->geometry();
  std::uniform_real_distribution<double> ux(0, size[0] - 1), uy(0, size[1] - 1), uz(0, size[2] - 1);
  for (int i = 0; i < 2000; ++i) {
    // Bias half the samples onto brick boundaries (fractional part between the last interior
    // voxel and the apron).
    Vec3 base{static_cast<int64_t>(ux(rng)), static_cast<int64_t>(uy(rng)),
              static_cast<int64_t>(uz(rng))};
    if (i % 2 == 0) {
      for (int a = 0; a < 3; ++a) {
        const int64_t b = (base[a] / 4) * 4 + 3;
        if (b + 1 < size[a]) base[a] = b;
      }
    }
    const double fx = (rng() % 1000) / 1000.0, fy = (rng() % 1000) / 1000.0,
                 fz = (rng() % 1000) / 1000.0;
    const NodeKey leaf = g.NodeContaining(0, base);
    auto node = f.tree->GetNode(leaf);
    ASSERT_TRUE(node.has_value());
    ASSERT_TRUE(node->has_brick());
    std::vector<std::byte> brick(g.brick_bytes());
    ASSERT_TRUE(f.tree->ReadBrick(node->id, brick).ok());
    double from_brick = 0, from_source = 0;
    for (int k = 0; k < 2; ++k)
      for (int j = 0; j < 2; ++j)
        for (int i2 = 0; i2 < 2; ++i2) {
          const double w = (i2 ? fx : 1 - fx) * (j ? fy : 1 - fy) * (k ? fz : 1 - fz);
          const Vec3 p{base[0] + i2, base[1] + j, base[2] + k};
          from_brick += w * BrickSample(g, leaf, brick, p, 0);
          from_source += w * src.at(0, p[0], p[1], p[2]);
        }
    ASSERT_EQ(from_brick, from_source)
        << "at " << base[0] + fx << "," << base[1] + fy << "," << base[2] + fz;
  }
}

// Parent voxels are means of VALID children only: a 5x3x3 volume (odd on every axis) whose
// voxels are all 100 with background 0 must give 100 at every level, everywhere.
TEST(OctreeTest, VirtualVoxelsNeverCountInMeansOrStatistics) {
  const Vec3 size{5, 3, 3};
  SourceVolume src(size, 1);
  for (auto& v : src.data[0]) v = 100;
  src.at(0, 4, 2, 2) = 103;  // One different voxel in the corner keeps a path of bricks.
  OctreeOptions options;
  options.brick_size = {2, 2, 2};
  TreeFixture f = TreeFixture::Make(Params(size, {2, 2, 2}, 1, 2), options);
  ASSERT_TRUE(f.tree);
  InsertAll(*f.tree, src, ZSlabs(size));
  VerifyCompleteTree(*f.tree, src);
  // The corner leaf (4..5, 2..3, 2..3) holds one valid voxel: its average is that voxel.
  auto corner = f.tree->GetNode(NodeKey{0, {2, 1, 1}});
  ASSERT_TRUE(corner.has_value());
  EXPECT_EQ(corner->channels[0].avg, 103.0);
  auto root = f.tree->GetNode(f.tree->geometry().RootKey());
  ASSERT_TRUE(root.has_value());
  EXPECT_GE(root->channels[0].min, 100);  // A virtual 0 would drag it down.
}

// Nodes with unwritten voxels are never pruned, even when what is written so far is constant.
TEST(OctreeTest, IncompleteNodesAreNeverPruned) {
  const Vec3 size{8, 8, 8};
  SourceVolume src(size, 2);
  for (auto& v : src.data[0]) v = 5;
  for (auto& v : src.data[1]) v = 9;
  OctreeOptions options;
  options.brick_size = {4, 4, 4};
  TreeFixture f = TreeFixture::Make(Params(size, {4, 4, 4}, 2, 1), options);
  ASSERT_TRUE(f.tree);
  Octree& tree = *f.tree;
  // Channel 0 everywhere, channel 1 only for z < 4: the upper leaves are incomplete.
  InsertBox(tree, src, 0, Box{{0, 0, 0}, size});
  InsertBox(tree, src, 1, Box{{0, 0, 0}, {8, 8, 4}});
  for (int64_t i = 0; i < 8; ++i) {
    const NodeKey k{0, {i & 1, (i >> 1) & 1, (i >> 2) & 1}};
    auto n = tree.GetNode(k);
    ASSERT_TRUE(n.has_value()) << k.ToString();
    const bool lower = k.index[2] == 0;
    EXPECT_EQ(n->complete, lower) << k.ToString();
    // Lower leaves: complete and constant in both channels -> no brick. Upper leaves: channel 0
    // constant 5 (differs from background 0, so a brick was needed) and kept while incomplete.
    EXPECT_EQ(n->has_brick(), !lower) << k.ToString();
  }
  auto root = tree.GetNode(tree.geometry().RootKey());
  ASSERT_TRUE(root->has_children());
  EXPECT_TRUE(root->has_brick());
  // Completing channel 1 prunes everything down to the root.
  InsertBox(tree, src, 1, Box{{0, 0, 4}, {8, 8, 8}});
  root = tree.GetNode(tree.geometry().RootKey());
  EXPECT_TRUE(root->complete);
  EXPECT_FALSE(root->has_children());
  EXPECT_FALSE(root->has_brick());
  EXPECT_EQ(root->channels[0].avg, 5.0);
  EXPECT_EQ(root->channels[1].avg, 9.0);
  EXPECT_EQ(tree.stats(), (OctreeStats{1, 0, 1, 0}));
  VerifyCompleteTree(tree, src);
}

// Overwrites replace values everywhere; with threshold 0 nothing is lost, so the tree equals
// one built from the final values directly.
TEST(OctreeTest, OverwriteReplacesValuesEverywhere) {
  const Vec3 size{12, 10, 7};
  SourceVolume first = MakePatternVolume(size, 2, 2, 1);
  SourceVolume second = first;
  const Box patch{{2, 3, 1}, {11, 9, 5}};  // Crosses pruned constant regions and bricks.
  for (int c = 0; c < 2; ++c)
    for (int64_t z = patch.lo[2]; z < patch.hi[2]; ++z)
      for (int64_t y = patch.lo[1]; y < patch.hi[1]; ++y)
        for (int64_t x = patch.lo[0]; x < patch.hi[0]; ++x)
          second.at(c, x, y, z) = static_cast<uint16_t>(1000 + x * y + c);
  OctreeOptions options;
  options.brick_size = {4, 2, 2};
  const auto params = Params(size, {4, 2, 2}, 2, 2);
  TreeFixture f = TreeFixture::Make(params, options);
  ASSERT_TRUE(f.tree);
  InsertAll(*f.tree, first, ZSlabs(size));
  for (int c = 0; c < 2; ++c) InsertBox(*f.tree, second, c, patch);
  VerifyCompleteTree(*f.tree, second);
  TreeFixture direct = TreeFixture::Make(params, options);
  InsertAll(*direct.tree, second, ZSlabs(size));
  ExpectSameTree(DumpTree(*direct.tree), DumpTree(*f.tree), "overwrite vs direct");
  // Overwriting a pruned region back to a constant prunes it again.
  for (int c = 0; c < 2; ++c) InsertBox(*f.tree, first, c, patch);
  TreeFixture again = TreeFixture::Make(params, options);
  InsertAll(*again.tree, first, ZSlabs(size));
  ExpectSameTree(DumpTree(*again.tree), DumpTree(*f.tree), "overwrite back");
}

// With a threshold the pruned brick's sub-threshold detail is gone; an overwrite brings back the
// new voxels (exactly) and the rest of the node shows its old average.
TEST(OctreeTest, OverwriteOfALossyPrunedNodeRestoresTheAverageAroundTheNewData) {
  const Vec3 size{8, 8, 8};
  SourceVolume src(size, 1);
  for (int64_t z = 0; z < 8; ++z)
    for (int64_t y = 0; y < 8; ++y)
      for (int64_t x = 0; x < 8; ++x)
        src.at(0, x, y, z) = static_cast<uint16_t>(100 + (x + y + z) % 2);
  OctreeOptions options;
  options.brick_size = {4, 4, 4};
  options.homogeneity_tolerance = {1};
  TreeFixture f = TreeFixture::Make(Params(size, {4, 4, 4}, 1, 2), options);
  ASSERT_TRUE(f.tree);
  InsertAll(*f.tree, src, ZSlabs(size));
  auto root = f.tree->GetNode(f.tree->geometry().RootKey());
  ASSERT_FALSE(root->has_children());  // All within tolerance: everything pruned.
  // Leaves average 100.5; level 1 (the root) holds round-half-up means of 4 x 100 + 4 x 101 = 101.
  ASSERT_EQ(root->channels[0].avg, 101.0);
  const std::vector<std::byte> one{std::byte{0xe8}, std::byte{0x03}};  // 1000.
  ASSERT_TRUE(f.tree->Insert(0, Box{{1, 1, 1}, {2, 2, 2}}, one).ok());
  auto leaf = f.tree->GetNode(NodeKey{0, {0, 0, 0}});
  ASSERT_TRUE(leaf.has_value());
  ASSERT_TRUE(leaf->has_brick());
  std::vector<std::byte> brick(f.tree->geometry().brick_bytes());
  ASSERT_TRUE(f.tree->ReadBrick(leaf->id, brick).ok());
  const BrickGeometry& g = f.tree->geometry();
  EXPECT_EQ(BrickSample(g, leaf->key, brick, {1, 1, 1}, 0), 1000);
  // The recreated leaf shows the pruned root's average: the old 100/101 detail is gone.
  EXPECT_EQ(BrickSample(g, leaf->key, brick, {0, 0, 0}, 0), 101);
  EXPECT_EQ(BrickSample(g, leaf->key, brick, {3, 2, 1}, 0), 101);
  EXPECT_EQ(leaf->channels[0].max, 1000);
}

// Several consumers replay the change log at different speeds into mirrors (id -> node, brick
// bytes, tests/octree/change_mirror.h); each reproduces the tree exactly. The slowest, allowed
// only a tiny backlog, is told to resynchronise and recovers by walking the tree again.
TEST(OctreeTest, ChangeLogLetsSeveralConsumersMirrorTheTree) {
  const Vec3 size{32, 16, 8};
  const SourceVolume src = MakePatternVolume(size, 2, 2, 5);
  OctreeOptions options;
  options.brick_size = {4, 4, 2};
  TreeFixture f = TreeFixture::Make(Params(size, {4, 4, 2}, 2, 2), options);
  ASSERT_TRUE(f.tree);
  Octree& tree = *f.tree;
  ChangeMirror every(&tree, tree.SubscribeChanges());   // Syncs after every block.
  ChangeMirror third(&tree, tree.SubscribeChanges());   // After every third block.
  ChangeMirror slow(&tree, tree.SubscribeChanges(16));  // After every eighth; falls behind.
  int step = 0;
  const auto blocks_done = [&](const char* phase) {
    every.Sync();
    ASSERT_NO_FATAL_FAILURE(ExpectMirrors(tree, every, std::string(phase) + ", every block"));
    if (++step % 3 == 0) {
      third.Sync();
      ASSERT_NO_FATAL_FAILURE(ExpectMirrors(tree, third, std::string(phase) + ", every third"));
    }
    if (step % 8 == 0) slow.Sync();
  };
  for (const Box& b : RandomBlocks(size, 9)) {
    for (int c = 0; c < 2; ++c) InsertBox(tree, src, c, b);
    ASSERT_NO_FATAL_FAILURE(blocks_done("build"));
  }
  const uint64_t deleted_by_build = every.deleted();
  // A constant half volume: its subtree is pruned; then the pattern again: nodes are re-created,
  // reusing the freed ids.
  const Box half{{0, 0, 0}, {16, 16, 8}};
  std::vector<uint16_t> constant(half.VoxelCount(), 4321);
  for (int c = 0; c < 2; ++c) {
    ASSERT_TRUE(tree.Insert(c, half, std::as_bytes(std::span(constant))).ok());
  }
  ASSERT_NO_FATAL_FAILURE(blocks_done("pruned"));
  for (const Box& b : RandomBlocks(half.hi, 4)) {
    for (int c = 0; c < 2; ++c) InsertBox(tree, src, c, b);
    ASSERT_NO_FATAL_FAILURE(blocks_done("rebuilt"));
  }
  for (ChangeMirror* m : {&every, &third, &slow}) m->Sync();
  EXPECT_GT(every.created(), 8u);
  EXPECT_GT(deleted_by_build, 0u);               // The constant regions lost their subtrees.
  EXPECT_GT(every.deleted(), deleted_by_build);  // The constant half lost its subtree.
  EXPECT_EQ(every.resyncs(), 0);
  EXPECT_EQ(third.resyncs(), 0);
  EXPECT_GT(slow.resyncs(), 0);
  EXPECT_LT(third.events(), every.events());  // Coalesced over its longer windows.
  ExpectMirrors(tree, every, "every block");
  ExpectMirrors(tree, third, "every third block");
  ExpectMirrors(tree, slow, "slow, resynchronised");
}

TEST(OctreeTest, InsertRejectsBadArguments) {
  OctreeOptions options;
  options.brick_size = {4, 4, 4};
  TreeFixture f = TreeFixture::Make(Params({10, 10, 10}, {4, 4, 4}, 2, 2), options);
  ASSERT_TRUE(f.tree);
  std::vector<std::byte> data(2 * 8);
  const Box box{{0, 0, 0}, {2, 2, 2}};
  EXPECT_EQ(f.tree->Insert(2, box, data).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(f.tree->Insert(-1, box, data).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(f.tree->Insert(0, Box{{9, 9, 9}, {11, 11, 11}}, data).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(f.tree->Insert(0, Box{{-1, 0, 0}, {1, 2, 2}}, data).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(f.tree->Insert(0, Box{}, {}).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(f.tree->Insert(0, box, std::span(data).first(15)).code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(f.tree->Insert(0, box, data).ok());
  EXPECT_EQ(f.tree->ReadBrick(0, std::span<std::byte>()).code(), StatusCode::kInvalidArgument);
  std::vector<std::byte> brick(f.tree->geometry().brick_bytes());
  EXPECT_EQ(f.tree->ReadBrick(12345, brick).code(), StatusCode::kNotFound);
}

TEST(OctreeTest, CreateRejectsBadOptions) {
  paging::MemoryPageStore store(1024);
  paging::PageCache cache(&store, 1 << 20);
  volume::VolumeInfo info;
  info.size = {100, 50, 20};
  info.channels.resize(2);
  info.dtype = volume::DataType::kUint16;
  OctreeOptions options;  // 64^3 bricks of 2 channels x 2 bytes do not fit a 1 KiB page.
  EXPECT_EQ(Octree::Create(info, options, &cache).status().code(), StatusCode::kInvalidArgument);
  options.brick_size = {4, 4, 4};
  EXPECT_TRUE(Octree::Create(info, options, &cache).ok());
  options.background = {1};  // One entry for two channels.
  EXPECT_EQ(Octree::Create(info, options, &cache).status().code(), StatusCode::kInvalidArgument);
  options.background = {};
  options.homogeneity_threshold = 2.0;
  EXPECT_EQ(Octree::Create(info, options, &cache).status().code(), StatusCode::kInvalidArgument);
  options.homogeneity_threshold = 0.05;
  auto tree = Octree::Create(info, options, &cache);
  ASSERT_TRUE(tree.ok());
  EXPECT_EQ((*tree)->tolerance(0), 3276u);  // floor(0.05 * 65535).
  info.dtype = volume::DataType::kUint8;
  options.brick_size = {5, 4, 4};  // Odd.
  EXPECT_FALSE(Octree::Create(info, options, &cache).ok());
  options.brick_size = {4, 4, 4};
  tree = Octree::Create(info, options, &cache);
  ASSERT_TRUE(tree.ok());
  EXPECT_EQ((*tree)->geometry().bytes_per_sample(), 1);
  EXPECT_EQ((*tree)->tolerance(0), 12u);  // floor(0.05 * 255).
}

}  // namespace
}  // namespace octoscope::octree
