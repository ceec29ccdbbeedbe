#include "session/frame_policy.h"

#include <gtest/gtest.h>

namespace octoscope::session {
namespace {

using std::chrono::milliseconds;

class FramePolicyTest : public ::testing::Test {
 protected:
  Clock::time_point t0_ = Clock::time_point{} + std::chrono::hours(1);
  Clock::time_point At(int ms) const { return t0_ + milliseconds(ms); }
};

TEST_F(FramePolicyTest, AChangeGetsAnInteractiveFrameThenARefinementWhenQuiet) {
  FramePolicy p;
  EXPECT_FALSE(p.Poll(At(0)).has_value());
  p.OnChange(1, At(0));
  auto order = p.Poll(At(0));
  ASSERT_TRUE(order.has_value());
  EXPECT_FALSE(order->refine);
  EXPECT_FALSE(order->lod_view_spacing);  // Interactive: the finest spacing (cheaper).
  EXPECT_EQ(order->version, 1u);
  EXPECT_FALSE(p.Poll(At(10)).has_value());  // One in flight.
  p.OnFrameDone(order->sequence, true, 50);
  std::optional<Clock::time_point> wake;
  EXPECT_FALSE(p.Poll(At(60), &wake).has_value());
  ASSERT_TRUE(wake.has_value());
  EXPECT_EQ(*wake, At(200));  // The idle delay after the change.
  auto refine = p.Poll(At(200));
  ASSERT_TRUE(refine.has_value());
  EXPECT_TRUE(refine->refine);
  EXPECT_TRUE(refine->lod_view_spacing);  // At rest: every axis at the screen's resolution.
  EXPECT_EQ(refine->scale, 1.0);
  EXPECT_EQ(refine->version, 1u);
  p.OnFrameDone(refine->sequence, true, 900);
  EXPECT_FALSE(p.Poll(At(2000), &wake).has_value());
  EXPECT_FALSE(wake.has_value());  // Nothing more to do.
  EXPECT_EQ(p.final_version(), 1u);
}

TEST_F(FramePolicyTest, LatestStateWinsWhileAFrameRenders) {
  FramePolicy p;
  p.OnChange(1, At(0));
  auto first = p.Poll(At(0));
  for (uint64_t v = 2; v <= 9; ++v) {
    p.OnChange(v, At(static_cast<int>(v)));
    EXPECT_FALSE(p.Poll(At(static_cast<int>(v))).has_value());
  }
  p.OnFrameDone(first->sequence, true, 40);
  auto next = p.Poll(At(40));
  ASSERT_TRUE(next.has_value());
  EXPECT_EQ(next->version, 9u);  // Versions 2..8 were never rendered.
  EXPECT_FALSE(next->refine);
}

TEST_F(FramePolicyTest, NoRefinementWhileInteracting) {
  FramePolicy p;
  p.OnInteraction(true, At(0));
  p.OnChange(1, At(0));
  auto o = p.Poll(At(0));
  p.OnFrameDone(o->sequence, true, 50);
  EXPECT_FALSE(p.Poll(At(5000)).has_value());  // Held: the user still has the mouse down.
  p.OnInteraction(false, At(5000));
  EXPECT_FALSE(p.Poll(At(5100)).has_value());
  auto r = p.Poll(At(5200));
  ASSERT_TRUE(r.has_value());
  EXPECT_TRUE(r->refine);
}

TEST_F(FramePolicyTest, AChangeSupersedesARefinementAtOnce) {
  FramePolicy p;
  p.OnChange(1, At(0));
  auto o = p.Poll(At(0));
  p.OnFrameDone(o->sequence, true, 30);
  auto r = p.Poll(At(300));
  ASSERT_TRUE(r.has_value() && r->refine);
  p.OnChange(2, At(400));
  auto i = p.Poll(At(400));
  ASSERT_TRUE(i.has_value());
  EXPECT_FALSE(i->refine);
  EXPECT_EQ(i->version, 2u);
  // The superseded refinement's late result changes nothing.
  p.OnFrameDone(r->sequence, true, 2000);
  EXPECT_TRUE(p.in_flight());
  p.OnFrameDone(i->sequence, true, 30);
  auto r2 = p.Poll(At(600));
  ASSERT_TRUE(r2.has_value() && r2->refine);
  EXPECT_EQ(r2->version, 2u);
}

TEST_F(FramePolicyTest, ScaleFollowsTheFrameTimeTargetWithinBounds) {
  FramePolicyOptions options;
  options.target_frame_ms = 100;
  options.min_scale = 0.25;
  EXPECT_EQ(FramePolicy(options).scale(), 0.5);  // The default first scale.
  options.initial_scale = 1;
  FramePolicy p(options);
  uint64_t v = 0;
  auto frame = [&](double ms) {
    ++v;
    p.OnChange(v, At(static_cast<int>(v)));
    auto o = p.Poll(At(static_cast<int>(v)));
    EXPECT_TRUE(o.has_value());
    p.OnFrameDone(o->sequence, true, ms);
    return o->scale;
  };
  EXPECT_EQ(frame(400), 1.0);  // The first frame at the initial scale.
  EXPECT_EQ(p.scale(), 0.5);   // 4x too slow: half the pixels per axis.
  for (int i = 0; i < 10; ++i) frame(400);
  EXPECT_EQ(p.scale(), 0.25);  // Never below the minimum.
  frame(110);                  // Within the dead band: unchanged.
  EXPECT_EQ(p.scale(), 0.25);
  for (int i = 0; i < 20; ++i) frame(10);
  EXPECT_EQ(p.scale(), 1.0);  // Fast frames grow back, at most to 1.
  // Refinement times never move the scale.
  p.OnChange(++v, At(1000));
  auto o = p.Poll(At(1000));
  p.OnFrameDone(o->sequence, true, 10);
  auto r = p.Poll(At(2000));
  ASSERT_TRUE(r.has_value() && r->refine);
  p.OnFrameDone(r->sequence, true, 5000);
  EXPECT_EQ(p.scale(), 1.0);
}

TEST_F(FramePolicyTest, InvalidateRendersTheSameVersionAgain) {
  FramePolicy p;
  p.OnChange(1, At(0));
  auto o = p.Poll(At(0));
  p.OnFrameDone(o->sequence, true, 10);
  auto r = p.Poll(At(200));
  p.OnFrameDone(r->sequence, true, 10);
  EXPECT_FALSE(p.Poll(At(500)).has_value());
  p.Invalidate(At(500));  // E.g. the viewport was resized.
  auto again = p.Poll(At(500));
  ASSERT_TRUE(again.has_value());
  EXPECT_EQ(again->version, 1u);
}

TEST_F(FramePolicyTest, NewDataRefinesAQuietViewAtOnceAndWaitsForAnInteractiveFrame) {
  FramePolicy p;
  p.OnChange(1, At(0));
  auto first = p.Poll(At(0));
  ASSERT_TRUE(first.has_value());
  p.OnFrameDone(first->sequence, true, 20);
  auto refine = p.Poll(At(200));
  ASSERT_TRUE(refine.has_value() && refine->refine);
  // Data arrives during the refinement: a new refinement supersedes it at once (no quiet wait,
  // no interactive frame in between).
  p.OnDataChange(2);
  auto again = p.Poll(At(210));
  ASSERT_TRUE(again.has_value());
  EXPECT_TRUE(again->refine);
  EXPECT_EQ(again->version, 2u);
  // While the user interacts, new data waits for the interactive frame in flight.
  p.OnInteraction(true, At(300));
  p.OnChange(3, At(300));
  auto interactive = p.Poll(At(300));
  ASSERT_TRUE(interactive.has_value());
  EXPECT_FALSE(interactive->refine);
  p.OnDataChange(4);
  EXPECT_FALSE(p.Poll(At(310)).has_value());
  p.OnFrameDone(interactive->sequence, true, 20);
  auto next = p.Poll(At(320));
  ASSERT_TRUE(next.has_value());
  EXPECT_FALSE(next->refine);
  EXPECT_EQ(next->version, 4u);
}

}  // namespace
}  // namespace octoscope::session
