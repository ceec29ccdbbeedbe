// Aspect groups: which participants share a render (docs/protocol.md "Per-participant frames").
#include "session/aspect_groups.h"

#include <gtest/gtest.h>

namespace octoscope::session {
namespace {

TEST(AspectGroupsTest, SameAspectWithinOnePercentShareTheLargestRender) {
  auto groups = GroupByAspect({{1, {400, 300}, 0}, {2, {800, 600}, 0}, {3, {401, 300}, 0}});
  ASSERT_EQ(groups.size(), 1u);
  EXPECT_EQ(groups[0].pixels.width, 800);
  EXPECT_EQ(groups[0].pixels.height, 600);
  EXPECT_EQ(groups[0].members, (std::vector<uint64_t>{2, 3, 1}));  // Largest first.
}

TEST(AspectGroupsTest, OtherAspectsAndBiasesRenderSeparately) {
  auto groups = GroupByAspect({{1, {400, 300}, 0},
                               {2, {300, 300}, 0},
                               {3, {412, 300}, 0},  // 1.373 vs 1.333: 3 % off.
                               {4, {800, 600}, 1},
                               {5, {0, 0}, 0}});  // Not shown: in no group.
  ASSERT_EQ(groups.size(), 4u);
  size_t members = 0;
  for (const auto& g : groups) members += g.members.size();
  EXPECT_EQ(members, 4u);
  EXPECT_EQ(groups[0].members, (std::vector<uint64_t>{4}));  // The largest, bias 1.
  EXPECT_EQ(groups[0].lod_bias, 1);
}

TEST(AspectGroupsTest, SameAspectIsSymmetricAndRefusesEmptySizes) {
  EXPECT_TRUE(SameAspect({100, 100}, {101, 100}));
  EXPECT_TRUE(SameAspect({101, 100}, {100, 100}));
  EXPECT_FALSE(SameAspect({100, 100}, {102, 100}));
  EXPECT_FALSE(SameAspect({0, 100}, {0, 100}));
}

TEST(AspectGroupsTest, MemberFramesScaleWithTheRender) {
  // Full resolution: the member's own size.
  auto s = MemberFrameSize({400, 300}, {800, 600}, {800, 600});
  EXPECT_EQ(s.width, 400);
  EXPECT_EQ(s.height, 300);
  // An interactive render at half scale: the member's frame at half scale too.
  s = MemberFrameSize({400, 300}, {800, 600}, {400, 300});
  EXPECT_EQ(s.width, 200);
  EXPECT_EQ(s.height, 150);
  // The group's largest member gets the render as it is.
  s = MemberFrameSize({800, 600}, {800, 600}, {203, 152});
  EXPECT_EQ(s.width, 203);
  EXPECT_EQ(s.height, 152);
  // Never empty, never larger than the render.
  s = MemberFrameSize({1, 1}, {800, 600}, {200, 150});
  EXPECT_EQ(s.width, 1);
  EXPECT_EQ(s.height, 1);
}

}  // namespace
}  // namespace octoscope::session
