#include "protocol/view_id.h"

namespace octoscope::protocol {

std::string_view ViewName(ViewId view) {
  switch (view) {
    case ViewId::k3d:
      return "3d";
    case ViewId::kX:
      return "x";
    case ViewId::kY:
      return "y";
    case ViewId::kZ:
      return "z";
  }
  return "?";
}

std::optional<ViewId> ViewFromName(std::string_view name) {
  for (int code = 0; code < kViewCount; ++code) {
    const ViewId view = static_cast<ViewId>(code);
    if (ViewName(view) == name) return view;
  }
  return std::nullopt;
}

std::optional<ViewId> ViewFromCode(uint8_t code) {
  if (code >= kViewCount) return std::nullopt;
  return static_cast<ViewId>(code);
}

}  // namespace octoscope::protocol
