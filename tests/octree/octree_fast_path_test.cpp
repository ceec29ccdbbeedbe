// Tests of the construction fast paths (octree.cpp's row kernels): every channel count the kernels
// specialise (1-4 channels: compile-time stride and whole-voxel words) and one they do not (5),
// both sample sizes, slabs that are / are not aligned to bricks and to parent groups (the step-2
// shortcut that reuses the inserted values), and the statistics of partially written bricks (step
// 3 merges the written part's statistics with a scan of the rest). Expectations come from the
// independent reference (octree_reference.h) and from scanning the stored bricks in the test.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "octree/octree.h"
#include "octree_reference.h"

namespace octoscope::octree {
namespace {

using testing::BrickSample;
using testing::BuildReference;
using testing::DumpTree;
using testing::ExpectSameTree;
using testing::InsertBox;
using testing::MakePatternVolume;
using testing::Params;
using testing::ReferencePyramid;
using testing::ReferenceStats;
using testing::SourceVolume;
using testing::TreeFixture;

void InsertSlabs(Octree& tree, const SourceVolume& src, int64_t planes) {
  for (int64_t z = 0; z < src.size[2]; z += planes) {
    const Box box{{0, 0, z}, {src.size[0], src.size[1], std::min(z + planes, src.size[2])}};
    for (int c = 0; c < src.channels; ++c) ASSERT_NO_FATAL_FAILURE(InsertBox(tree, src, c, box));
  }
}

// Every node's statistics equal the reference's, and every brick's valid interior holds the
// reference level (complete tree).
void ExpectMatchesReference(const Octree& tree, const SourceVolume& src) {
  const BrickGeometry& g = tree.geometry();
  std::vector<uint16_t> bg(src.channels);
  for (int c = 0; c < src.channels; ++c) bg[c] = tree.background(c);
  const ReferencePyramid ref = BuildReference(src, g.level_count(), bg);
  for (const testing::NodeDump& node : DumpTree(tree)) {
    if (node.is_virtual) continue;
    EXPECT_TRUE(node.complete) << node.key.ToString();
    const Box valid = g.ValidBox(node.key);
    for (int c = 0; c < src.channels; ++c) {
      const auto own = ReferenceStats(ref, node.key.level, c, valid);
      EXPECT_EQ(node.channels[c].min, own.min) << node.key.ToString() << " c" << c;
      EXPECT_EQ(node.channels[c].max, own.max) << node.key.ToString() << " c" << c;
      EXPECT_EQ(node.channels[c].avg, own.avg) << node.key.ToString() << " c" << c;
      if (!node.has_brick) continue;
      for (int64_t z = valid.lo[2]; z < valid.hi[2]; ++z)
        for (int64_t y = valid.lo[1]; y < valid.hi[1]; ++y)
          for (int64_t x = valid.lo[0]; x < valid.hi[0]; ++x) {
            ASSERT_EQ(BrickSample(g, node.key, node.brick, {x, y, z}, c),
                      ref.at(node.key.level, c, {x, y, z}))
                << node.key.ToString() << " voxel " << x << "," << y << "," << z << " c" << c;
          }
    }
  }
}

struct KernelCase {
  int channels;
  int bps;
};

class OctreeKernelTest : public ::testing::TestWithParam<KernelCase> {};

// Brick-aligned slabs (whole bricks written at once), slabs of odd thickness (blocks that split
// parent groups, so step 2 reads the neighbours back) and single planes all give the one-shot
// tree, which matches the reference.
TEST_P(OctreeKernelTest, SlabShapesGiveTheReferenceTree) {
  const KernelCase& kc = GetParam();
  const Vec3 size{37, 22, 19};
  const Vec3 brick{8, 6, 4};
  const SourceVolume src = MakePatternVolume(size, kc.channels, kc.bps, 3);
  OctreeOptions options;
  options.brick_size = brick;
  options.homogeneity_threshold = 0.02;
  options.background.assign(kc.channels, 7);
  const auto params = Params(size, brick, kc.channels, kc.bps);

  TreeFixture one_shot = TreeFixture::Make(params, options);
  ASSERT_TRUE(one_shot.tree);
  InsertSlabs(*one_shot.tree, src, size[2]);
  ExpectMatchesReference(*one_shot.tree, src);
  const std::vector<testing::NodeDump> expected = DumpTree(*one_shot.tree);
  for (int64_t planes : {int64_t{4}, int64_t{3}, int64_t{1}}) {
    SCOPED_TRACE("slabs of " + std::to_string(planes) + " planes");
    TreeFixture f = TreeFixture::Make(params, options);
    ASSERT_TRUE(f.tree);
    InsertSlabs(*f.tree, src, planes);
    ExpectSameTree(expected, DumpTree(*f.tree), "slabs");
    EXPECT_EQ(f.tree->stats(), one_shot.tree->stats());
  }
}

INSTANTIATE_TEST_SUITE_P(Layouts, OctreeKernelTest,
                         ::testing::Values(KernelCase{1, 1}, KernelCase{1, 2}, KernelCase{2, 1},
                                           KernelCase{2, 2}, KernelCase{3, 2}, KernelCase{4, 1},
                                           KernelCase{4, 2}, KernelCase{5, 1}, KernelCase{5, 2}),
                         [](const ::testing::TestParamInfo<KernelCase>& info) {
                           return std::to_string(info.param.channels) + "ch_" +
                                  std::to_string(8 * info.param.bps) + "bit";
                         });

// While a brick is only partly written, its statistics still cover its whole valid interior:
// the written part (known from the insert) merged with the rest (scanned), including the
// initial uniform value and the apron-free interior. Checked against a scan of the stored brick.
TEST(OctreeKernelTest, StatisticsOfPartlyWrittenBricksCoverTheWholeBrick) {
  const Vec3 size{20, 12, 16};
  const Vec3 brick{8, 8, 8};
  const SourceVolume src = MakePatternVolume(size, 2, 2, 5);
  OctreeOptions options;
  options.brick_size = brick;
  options.background = {300, 4};
  TreeFixture f = TreeFixture::Make(Params(size, brick, 2, 2), options);
  ASSERT_TRUE(f.tree);
  Octree& tree = *f.tree;
  const BrickGeometry& g = tree.geometry();
  const std::vector<Box> blocks = {Box{{0, 0, 0}, {20, 12, 3}}, Box{{3, 2, 3}, {17, 9, 8}},
                                   Box{{0, 0, 8}, {9, 12, 16}}, Box{{5, 1, 2}, {6, 11, 12}}};
  for (const Box& box : blocks) {
    for (int c = 0; c < 2; ++c) {
      ASSERT_TRUE(tree.Insert(c, box, src.Block(c, box, 2)).ok()) << box.ToString();
    }
    for (const testing::NodeDump& node : DumpTree(tree)) {
      if (!node.has_brick) continue;
      const Box valid = g.ValidBox(node.key);
      for (int c = 0; c < 2; ++c) {
        uint32_t lo = 0xffff, hi = 0;
        uint64_t sum = 0;
        for (int64_t z = valid.lo[2]; z < valid.hi[2]; ++z)
          for (int64_t y = valid.lo[1]; y < valid.hi[1]; ++y)
            for (int64_t x = valid.lo[0]; x < valid.hi[0]; ++x) {
              const uint32_t v = BrickSample(g, node.key, node.brick, {x, y, z}, c);
              lo = std::min(lo, v);
              hi = std::max(hi, v);
              sum += v;
            }
        const std::string where =
            node.key.ToString() + " c" + std::to_string(c) + " after " + box.ToString();
        EXPECT_EQ(node.channels[c].min, lo) << where;
        EXPECT_EQ(node.channels[c].max, hi) << where;
        EXPECT_EQ(node.channels[c].avg,
                  static_cast<double>(sum) / static_cast<double>(valid.VoxelCount()))
            << where;
      }
    }
  }
}

}  // namespace
}  // namespace octoscope::octree
