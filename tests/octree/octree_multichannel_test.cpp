// Multi-channel inserts, parallel brick writes, exact statistics during thin inserts and the
// pruning error bound: each checked against the per-channel sequential build or the naive
// reference pyramid (octree_reference.h).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "octree/octree.h"
#include "octree_reference.h"
#include "util/worker_pool.h"

namespace octoscope::octree {
namespace {

using testing::BuildReference;
using testing::DumpTree;
using testing::ExpectSameTree;
using testing::MakePatternVolume;
using testing::Params;
using testing::ReferenceStats;
using testing::SourceVolume;
using testing::TreeFixture;

struct Case {
  Vec3 size;
  Vec3 brick;
  int channels;
  int bps;
  double threshold;
};

class MultiChannelTest : public ::testing::TestWithParam<Case> {};

// Inserts all channels of `box` in one call.
Status InsertAll(Octree& tree, const SourceVolume& src, const Box& box,
                 const std::vector<int>& channels, WorkerPool* workers = nullptr) {
  std::vector<std::vector<std::byte>> data;
  std::vector<ChannelBlock> blocks;
  for (int c : channels) data.push_back(src.Block(c, box, tree.geometry().bytes_per_sample()));
  for (size_t i = 0; i < channels.size(); ++i) blocks.push_back({channels[i], data[i]});
  return tree.Insert(box, blocks, workers);
}

TEST_P(MultiChannelTest, EveryWayOfInsertingGivesTheSameTree) {
  const Case& p = GetParam();
  const SourceVolume src = MakePatternVolume(p.size, p.channels, p.bps, 7);
  OctreeOptions options;
  options.brick_size = p.brick;
  options.homogeneity_threshold = p.threshold;
  const auto params = Params(p.size, p.brick, p.channels, p.bps);
  const Box all{{0, 0, 0}, p.size};

  TreeFixture reference = TreeFixture::Make(params, options);
  ASSERT_TRUE(reference.tree);
  for (int c = 0; c < p.channels; ++c)
    ASSERT_TRUE(testing::InsertBlock(*reference.tree, src, c, all).ok());
  const auto expected = DumpTree(*reference.tree);

  std::vector<int> every(p.channels);
  for (int c = 0; c < p.channels; ++c) every[c] = c;
  WorkerPool pool(3);
  for (bool parallel : {false, true}) {
    const OctreeOptions& o = options;
    WorkerPool* w = parallel ? &pool : nullptr;
    const std::string mode = parallel ? " (parallel)" : "";
    {  // One multi-channel insert.
      TreeFixture f = TreeFixture::Make(params, o);
      ASSERT_TRUE(InsertAll(*f.tree, src, all, every, w).ok());
      ExpectSameTree(expected, DumpTree(*f.tree), "one multi-channel insert" + mode);
    }
    {  // Single planes, all channels at once, in random order.
      TreeFixture f = TreeFixture::Make(params, o);
      std::vector<Box> planes = testing::ZSlabs(p.size);
      std::shuffle(planes.begin(), planes.end(), std::mt19937(3));
      for (const Box& b : planes) ASSERT_TRUE(InsertAll(*f.tree, src, b, every, w).ok());
      ExpectSameTree(expected, DumpTree(*f.tree), "shuffled multi-channel planes" + mode);
    }
    {  // Random blocks of random channel subsets until every voxel of every channel is written
       // (overlaps rewrite the same values).
      TreeFixture f = TreeFixture::Make(params, o);
      std::mt19937 rng(11);
      // A grid of cells, each written as one block with a random channel subset, then the
      // missing channels of the cell; cells in random order.
      std::vector<Box> cells;
      const Vec3 cell{std::max<int64_t>(1, p.size[0] / 3), std::max<int64_t>(1, p.size[1] / 2),
                      std::max<int64_t>(1, p.size[2] / 3)};
      for (int64_t z = 0; z < p.size[2]; z += cell[2])
        for (int64_t y = 0; y < p.size[1]; y += cell[1])
          for (int64_t x = 0; x < p.size[0]; x += cell[0])
            cells.push_back(Box{{x, y, z},
                                {std::min(x + cell[0], p.size[0]), std::min(y + cell[1], p.size[1]),
                                 std::min(z + cell[2], p.size[2])}});
      std::shuffle(cells.begin(), cells.end(), rng);
      for (const Box& b : cells) {
        std::vector<int> first, second;
        for (int c = 0; c < p.channels; ++c) (rng() % 2 ? first : second).push_back(c);
        if (!first.empty()) {
          ASSERT_TRUE(InsertAll(*f.tree, src, b, first, w).ok());
        }
        if (!second.empty()) {
          ASSERT_TRUE(InsertAll(*f.tree, src, b, second, w).ok());
        }
      }
      ExpectSameTree(expected, DumpTree(*f.tree), "random cells and channel subsets" + mode);
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Shapes, MultiChannelTest,
                         ::testing::Values(Case{{24, 20, 16}, {4, 4, 4}, 3, 2, 0.0},
                                           Case{{24, 20, 16}, {4, 4, 4}, 3, 2, 0.05},
                                           Case{{17, 9, 13}, {4, 2, 6}, 2, 1, 0.0},
                                           Case{{33, 7, 5}, {8, 4, 4}, 5, 2, 0.02},
                                           Case{{16, 16, 16}, {8, 8, 8}, 1, 2, 0.0},
                                           Case{{20, 12, 9}, {4, 4, 2}, 4, 1, 0.1}));

// While planes trickle in (thin, partial-width blocks), every node's statistics equal those of
// the naive pyramid of what was written so far (unwritten voxels show the background): the
// per-plane statistics kept for incomplete nodes never go stale.
TEST(MultiChannelTest, StatisticsStayExactWhilePlanesTrickleIn) {
  const Vec3 size{19, 14, 11};
  const int channels = 2;
  const SourceVolume src = MakePatternVolume(size, channels, 2, 5);
  OctreeOptions options;
  options.brick_size = {4, 4, 4};
  TreeFixture f = TreeFixture::Make(Params(size, options.brick_size, channels, 2), options);
  ASSERT_TRUE(f.tree);
  const BrickGeometry& g = f.tree->geometry();
  std::vector<bool> written(static_cast<size_t>(size[0] * size[1] * size[2]), false);
  std::mt19937 rng(9);
  // Each plane in two halves along x (partial rows), the halves in random order per channel.
  std::vector<std::pair<int, Box>> blocks;
  for (int64_t z = 0; z < size[2]; ++z) {
    for (int c = 0; c < channels; ++c) {
      blocks.push_back({c, Box{{0, 0, z}, {7, size[1], z + 1}}});
      blocks.push_back({c, Box{{7, 0, z}, {size[0], size[1], z + 1}}});
    }
  }
  std::shuffle(blocks.begin(), blocks.end(), rng);
  std::vector<std::vector<bool>> channel_written(channels, written);
  int step = 0;
  for (const auto& [c, box] : blocks) {
    ASSERT_TRUE(testing::InsertBlock(*f.tree, src, c, box).ok());
    for (int64_t z = box.lo[2]; z < box.hi[2]; ++z)
      for (int64_t y = box.lo[1]; y < box.hi[1]; ++y)
        for (int64_t x = box.lo[0]; x < box.hi[0]; ++x)
          channel_written[c][static_cast<size_t>((z * size[1] + y) * size[0] + x)] = true;
    if (++step % 5 != 0 && step != static_cast<int>(blocks.size())) continue;
    for (int ch = 0; ch < channels; ++ch) {
      const auto ref = BuildReference(src, g.level_count(), {0, 0}, &channel_written[ch]);
      for (const testing::NodeDump& d : DumpTree(*f.tree)) {
        if (d.is_virtual) continue;
        const auto r = ReferenceStats(ref, d.key.level, ch, g.ValidBox(d.key));
        ASSERT_EQ(d.channels[ch].min, r.min) << d.key.ToString() << " step " << step;
        ASSERT_EQ(d.channels[ch].max, r.max) << d.key.ToString() << " step " << step;
        ASSERT_NEAR(d.channels[ch].avg, r.avg, 1e-9) << d.key.ToString() << " step " << step;
      }
    }
  }
}

// What each level-0 voxel shows: its own value where a leaf brick holds it, else the rounded
// average of the deepest node covering it.
uint16_t ShownValue(const Octree& tree, int c, const Vec3& p) {
  const BrickGeometry& g = tree.geometry();
  NodeKey key = g.RootKey();
  for (;;) {
    auto node = tree.GetNode(key);
    EXPECT_TRUE(node.has_value());
    if (key.level == 0 && node->has_brick()) return 0xffff;  // Exact (marker).
    if (!node->has_children()) {
      return static_cast<uint16_t>(std::floor(node->channels[c].avg + 0.5));
    }
    const int shift = key.level - 1;
    const int octant = static_cast<int>(((p[0] / g.brick_size()[0]) >> shift) & 1) |
                       static_cast<int>(((p[1] / g.brick_size()[1]) >> shift) & 1) << 1 |
                       static_cast<int>(((p[2] / g.brick_size()[2]) >> shift) & 1) << 2;
    key = ChildKey(key, octant);
  }
}

TEST(PruningErrorTest, EqualsTheLargestDeviationOfAnyShownVoxel) {
  const Vec3 size{24, 20, 16};
  const int channels = 2;
  const SourceVolume src = MakePatternVolume(size, channels, 2, 13);
  for (double threshold : {0.0, 0.02, 0.3}) {
    OctreeOptions options;
    options.brick_size = {4, 4, 4};
    options.homogeneity_threshold = threshold;
    TreeFixture f = TreeFixture::Make(Params(size, options.brick_size, channels, 2), options);
    ASSERT_TRUE(f.tree);
    for (int c = 0; c < channels; ++c) {
      ASSERT_TRUE(testing::InsertBlock(*f.tree, src, c, Box{{0, 0, 0}, size}).ok());
    }
    const std::vector<uint32_t> reported = f.tree->PruningError();
    for (int c = 0; c < channels; ++c) {
      uint32_t worst = 0;
      for (int64_t z = 0; z < size[2]; ++z)
        for (int64_t y = 0; y < size[1]; ++y)
          for (int64_t x = 0; x < size[0]; ++x) {
            const uint16_t shown = ShownValue(*f.tree, c, {x, y, z});
            if (shown == 0xffff) continue;
            const int d = std::abs(static_cast<int>(shown) - src.at(c, x, y, z));
            worst = std::max<uint32_t>(worst, static_cast<uint32_t>(d));
          }
      EXPECT_EQ(reported[c], worst) << "threshold " << threshold << " channel " << c;
      if (threshold == 0.0) {
        EXPECT_EQ(reported[c], 0u);
      }
      // The error never exceeds the tolerance the threshold allows.
      EXPECT_LE(reported[c], f.tree->tolerance(c));
    }
    if (threshold == 0.3) {
      EXPECT_GT(reported[0] + reported[1], 0u) << "the lossy case must prune";
    }
  }
}

}  // namespace
}  // namespace octoscope::octree

namespace octoscope::octree {
namespace {

using testing::Params;

// Node ids are 32-bit (8 * group + octant): a geometry whose largest tree could need more than
// 2^29 child groups is refused instead of wrapping ids later.
TEST(OctreeLimitsTest, GeometriesBeyondThirtyTwoBitNodeIdsAreRefused) {
  paging::MemoryPageStore store(1 << 20);
  paging::PageCache cache(&store, 16 << 20);
  auto too_deep = BrickGeometry::Create(Params({65536, 65536, 65536}, {32, 32, 32}, 1, 1));
  ASSERT_TRUE(too_deep.ok());
  auto refused = Octree::Create(*too_deep, OctreeOptions{}, &cache);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(refused.status().message().find("larger bricks"), std::string::npos);
  auto fits = BrickGeometry::Create(Params({65536, 65536, 65536}, {64, 64, 64}, 1, 1));
  ASSERT_TRUE(fits.ok());
  EXPECT_TRUE(Octree::Create(*fits, OctreeOptions{}, &cache).ok());
}

}  // namespace
}  // namespace octoscope::octree
