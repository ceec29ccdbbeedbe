// Tests of the octree's bookkeeping helper WriteCoverage (completeness); the change log has
// change_log_test.cpp.
#include <gtest/gtest.h>

#include <sstream>
#include <string>
#include <vector>

#include "octree/write_coverage.h"

namespace octoscope::octree {
namespace {

TEST(WriteCoverageTest, TracksRowsAndPartialRowsExactly) {
  WriteCoverage cov({5, 3, 2});
  EXPECT_FALSE(cov.complete());
  cov.Mark(Box{{0, 0, 0}, {5, 3, 1}});  // Whole rows of z = 0.
  EXPECT_EQ(cov.WrittenVoxels(), 15u);
  cov.Mark(Box{{0, 0, 1}, {2, 3, 2}});  // Partial rows.
  cov.Mark(Box{{1, 0, 1}, {3, 3, 2}});  // Overlapping partial rows.
  EXPECT_EQ(cov.WrittenVoxels(), 24u);
  EXPECT_FALSE(cov.complete());
  cov.Mark(Box{{3, 0, 1}, {9, 2, 5}});  // Clipped to the box; rows y 0,1 of z 1 now full.
  EXPECT_EQ(cov.WrittenVoxels(), 28u);
  EXPECT_FALSE(cov.complete());
  std::stringstream saved;
  cov.Save(saved);
  auto loaded = WriteCoverage::Load(saved, {5, 3, 2});
  ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
  EXPECT_EQ(*loaded, cov);
  cov.Mark(Box{{4, 2, 1}, {5, 3, 2}});
  EXPECT_FALSE(cov.complete());
  cov.Mark(Box{{3, 2, 1}, {4, 3, 2}});
  EXPECT_TRUE(cov.complete());
  EXPECT_EQ(cov.WrittenVoxels(), 30u);
}

TEST(WriteCoverageTest, LoadRejectsTruncatedAndInconsistentRecords) {
  WriteCoverage cov({5, 3, 2});
  cov.Mark(Box{{0, 0, 0}, {2, 1, 1}});
  std::stringstream saved;
  cov.Save(saved);
  const std::string bytes = saved.str();
  for (size_t n = 0; n < bytes.size(); ++n) {
    std::stringstream truncated(bytes.substr(0, n));
    EXPECT_FALSE(WriteCoverage::Load(truncated, {5, 3, 2}).ok()) << n;
  }
  std::string bad = bytes;
  bad[0] = static_cast<char>(0xff);  // Full-row bits beyond the 6 rows.
  std::stringstream bad_stream(bad);
  EXPECT_EQ(WriteCoverage::Load(bad_stream, {5, 3, 2}).status().code(), StatusCode::kCorrupt);
}

}  // namespace
}  // namespace octoscope::octree
