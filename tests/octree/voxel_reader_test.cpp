// ReadVoxels / CountVoxels read a tree back: built from a pattern volume with constant regions
// (pruned subtrees), a ramp and noise (bricks), lossless, the level-0 voxels read back equal the
// source exactly, and the counts equal an independent count of the source. A partly written tree
// reads the background where nothing was written.
#include "octree/voxel_reader.h"

#include <gtest/gtest.h>

#include <vector>

#include "octree_reference.h"

namespace octoscope::octree {
namespace {

using testing::MakePatternVolume;
using testing::SourceVolume;
using testing::TreeFixture;

struct Case {
  Vec3 size;
  Vec3 brick;
  int bps;
};

class VoxelReaderTest : public ::testing::TestWithParam<Case> {};

TEST_P(VoxelReaderTest, ReadsBackTheSourceAndCountsIt) {
  const Case k = GetParam();
  const SourceVolume src = MakePatternVolume(k.size, 2, k.bps, 3);
  OctreeOptions options;
  options.brick_size = k.brick;
  TreeFixture f = TreeFixture::Make(testing::Params(k.size, k.brick, 2, k.bps), options);
  ASSERT_TRUE(f.tree);
  const Box all{{0, 0, 0}, k.size};
  for (int c = 0; c < 2; ++c) ASSERT_NO_FATAL_FAILURE(testing::InsertBox(*f.tree, src, c, all));
  ASSERT_GT(f.tree->stats().homogeneous_nodes, 0u);  // Something was pruned.

  for (int c = 0; c < 2; ++c) {
    std::vector<uint16_t> out(all.VoxelCount());
    ASSERT_TRUE(ReadVoxels(*f.tree, c, all, out).ok());
    EXPECT_EQ(out, src.data[c]) << "channel " << c;
    // A single plane and an odd box.
    const Box plane{{0, 0, 5}, {k.size[0], k.size[1], 6}};
    std::vector<uint16_t> p(plane.VoxelCount());
    ASSERT_TRUE(ReadVoxels(*f.tree, c, plane, p).ok());
    for (int64_t y = 0; y < k.size[1]; ++y)
      for (int64_t x = 0; x < k.size[0]; ++x)
        ASSERT_EQ(p[y * k.size[0] + x], src.at(c, x, y, 5)) << x << "," << y;
    const Box odd{{3, 1, 2}, {k.size[0] - 2, 7, k.size[2] - 1}};
    std::vector<uint16_t> o(odd.VoxelCount());
    ASSERT_TRUE(ReadVoxels(*f.tree, c, odd, o).ok());
    size_t i = 0;
    for (int64_t z = odd.lo[2]; z < odd.hi[2]; ++z)
      for (int64_t y = odd.lo[1]; y < odd.hi[1]; ++y)
        for (int64_t x = odd.lo[0]; x < odd.hi[0]; ++x) ASSERT_EQ(o[i++], src.at(c, x, y, z));
  }

  const size_t bins = k.bps == 1 ? 256 : 65536;
  std::vector<std::vector<uint64_t>> counts(2, std::vector<uint64_t>(bins, 0));
  ASSERT_TRUE(CountVoxels(*f.tree, counts).ok());
  for (int c = 0; c < 2; ++c) {
    std::vector<uint64_t> expected(bins, 0);
    for (uint16_t v : src.data[c]) ++expected[v];
    EXPECT_EQ(counts[c], expected) << "channel " << c;
  }
}

INSTANTIATE_TEST_SUITE_P(Shapes, VoxelReaderTest,
                         ::testing::Values(Case{{40, 30, 20}, {8, 8, 4}, 2},
                                           Case{{49, 35, 9}, {8, 8, 8}, 1},
                                           Case{{64, 64, 8}, {16, 16, 8}, 2}));

TEST(VoxelReaderTest, UnwrittenVoxelsReadAsTheBackgroundAndBadArgumentsFail) {
  const Vec3 size{24, 24, 12};
  const SourceVolume src = MakePatternVolume(size, 1, 2, 4);
  OctreeOptions options;
  options.brick_size = {8, 8, 4};
  options.background = {7};
  TreeFixture f = TreeFixture::Make(testing::Params(size, options.brick_size, 1, 2), options);
  ASSERT_TRUE(f.tree);
  const Box half{{0, 0, 0}, {24, 24, 6}};
  ASSERT_NO_FATAL_FAILURE(testing::InsertBox(*f.tree, src, 0, half));
  const Box all{{0, 0, 0}, size};
  std::vector<uint16_t> out(all.VoxelCount());
  ASSERT_TRUE(ReadVoxels(*f.tree, 0, all, out).ok());
  for (int64_t z = 0; z < size[2]; ++z)
    for (int64_t y = 0; y < size[1]; ++y)
      for (int64_t x = 0; x < size[0]; ++x)
        ASSERT_EQ(out[(z * size[1] + y) * size[0] + x], z < 6 ? src.at(0, x, y, z) : 7);

  EXPECT_EQ(ReadVoxels(*f.tree, 1, all, out).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ReadVoxels(*f.tree, 0, Box{{0, 0, 0}, {25, 1, 1}}, out).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(ReadVoxels(*f.tree, 0, Box{{0, 0, 0}, {1, 1, 1}}, out).code(),
            StatusCode::kInvalidArgument);
  std::vector<std::vector<uint64_t>> wrong(1, std::vector<uint64_t>(256));
  EXPECT_EQ(CountVoxels(*f.tree, wrong).code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace octoscope::octree
