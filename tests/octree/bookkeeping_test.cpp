// Tests of the octree's bookkeeping helpers: WriteCoverage (completeness) and ChangeLog.
#include <gtest/gtest.h>

#include <sstream>
#include <string>
#include <vector>

#include "octree/change_log.h"
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

TEST(ChangeLogTest, CoalescesUpdatesButKeepsCreationsAndDeletionsInOrder) {
  ChangeLog log;
  log.Append(8, NodeChangeKind::kCreated);
  log.Append(8, NodeChangeKind::kUpdated);
  log.Append(0, NodeChangeKind::kUpdated);
  log.Append(8, NodeChangeKind::kUpdated);
  log.Append(8, NodeChangeKind::kDeleted);
  log.Append(8, NodeChangeKind::kCreated);
  EXPECT_EQ(log.pending(), 5u);
  const std::vector<NodeChange> expected{{8, NodeChangeKind::kCreated},
                                         {8, NodeChangeKind::kUpdated},
                                         {0, NodeChangeKind::kUpdated},
                                         {8, NodeChangeKind::kDeleted},
                                         {8, NodeChangeKind::kCreated}};
  EXPECT_EQ(log.Drain(), expected);
  EXPECT_EQ(log.pending(), 0u);
  log.Append(0, NodeChangeKind::kUpdated);  // A new window: reported again.
  EXPECT_EQ(log.Drain(), (std::vector<NodeChange>{{0, NodeChangeKind::kUpdated}}));
}

}  // namespace
}  // namespace octoscope::octree
