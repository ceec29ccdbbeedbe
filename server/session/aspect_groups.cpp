#include "session/aspect_groups.h"

#include <algorithm>
#include <cmath>

namespace octoscope::session {

bool SameAspect(const protocol::PixelSize& a, const protocol::PixelSize& b) {
  if (a.width <= 0 || a.height <= 0 || b.width <= 0 || b.height <= 0) return false;
  const double ra = static_cast<double>(a.width) / a.height;
  const double rb = static_cast<double>(b.width) / b.height;
  return std::abs(ra - rb) <= kAspectTolerance * std::max(ra, rb);
}

std::vector<AspectGroup> GroupByAspect(std::vector<GroupMember> members) {
  std::erase_if(members,
                [](const GroupMember& m) { return m.pixels.width <= 0 || m.pixels.height <= 0; });
  // Largest first (ties by participant), so each group's first member fixes its render size.
  std::stable_sort(members.begin(), members.end(), [](const GroupMember& a, const GroupMember& b) {
    const int64_t area_a = int64_t{a.pixels.width} * a.pixels.height;
    const int64_t area_b = int64_t{b.pixels.width} * b.pixels.height;
    if (area_a != area_b) return area_a > area_b;
    return a.participant < b.participant;
  });
  std::vector<AspectGroup> groups;
  for (const GroupMember& m : members) {
    auto it = std::find_if(groups.begin(), groups.end(), [&](const AspectGroup& g) {
      return g.lod_bias == m.lod_bias && SameAspect(g.pixels, m.pixels);
    });
    if (it == groups.end()) {
      groups.push_back({m.pixels, m.lod_bias, {}});
      it = groups.end() - 1;
    }
    it->members.push_back(m.participant);
  }
  return groups;
}

protocol::PixelSize MemberFrameSize(const protocol::PixelSize& member,
                                    const protocol::PixelSize& group,
                                    const protocol::PixelSize& rendered) {
  if (member.width == group.width && member.height == group.height) return rendered;
  auto scaled = [](int m, int g, int r) {
    const int v = static_cast<int>(std::lround(static_cast<double>(m) * r / std::max(1, g)));
    return std::clamp(v, 1, std::max(1, r));
  };
  return {scaled(member.width, group.width, rendered.width),
          scaled(member.height, group.height, rendered.height)};
}

}  // namespace octoscope::session
