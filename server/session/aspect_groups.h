// Aspect groups: which participants' viewports of one view share a render (docs/protocol.md,
// "Per-participant frames"). Viewports whose aspect ratios agree within kAspectTolerance (and
// whose level-of-detail bias is the same) form a group rendered once at its largest size; the
// others' frames are resampled down from it. Pure logic: no threads, no rendering.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_SESSION_ASPECT_GROUPS_H_
#define OCTOSCOPE_SESSION_ASPECT_GROUPS_H_

#include <cstdint>
#include <vector>

#include "protocol/ws_messages.h"

namespace octoscope::session {

inline constexpr double kAspectTolerance = 0.01;

struct GroupMember {
  uint64_t participant = 0;
  protocol::PixelSize pixels;  // Width and height >= 1.
  double lod_bias = 0;
};

struct AspectGroup {
  protocol::PixelSize pixels;  // The largest member's (by area): the render size.
  double lod_bias = 0;
  std::vector<uint64_t> members;  // Largest first.
};

// True when a viewport of `pixels` may be served from a render of `group` pixels (same aspect
// within kAspectTolerance, not larger).
bool SameAspect(const protocol::PixelSize& a, const protocol::PixelSize& b);

// Partitions `members` (0 x 0 ones are left out): largest first, each joins the first group of
// its lod_bias whose render size has its aspect, else starts a group. Deterministic.
std::vector<AspectGroup> GroupByAspect(std::vector<GroupMember> members);

// The size of a member's frame cut from a render of `rendered` pixels made for a group of
// `group` pixels (interactive frames render the group at a reduced scale): the member's share,
// at least 1 x 1 and at most `rendered`.
protocol::PixelSize MemberFrameSize(const protocol::PixelSize& member,
                                    const protocol::PixelSize& group,
                                    const protocol::PixelSize& rendered);

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_ASPECT_GROUPS_H_
