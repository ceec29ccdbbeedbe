// ViewId: the four views of a viewing session (docs/protocol.md): the 3-D view and the slice
// views through x, y and z. Messages name them "3d", "x", "y", "z"; frame headers carry the code.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_VIEW_ID_H_
#define OCTOSCOPE_PROTOCOL_VIEW_ID_H_

#include <cstdint>
#include <optional>
#include <string_view>

namespace octoscope::protocol {

// The values are the frame header's view codes.
enum class ViewId : uint8_t { k3d = 0, kX = 1, kY = 2, kZ = 3 };

inline constexpr int kViewCount = 4;

// "3d", "x", "y", "z".
std::string_view ViewName(ViewId view);
std::optional<ViewId> ViewFromName(std::string_view name);
// The view with frame-header code `code`, if any.
std::optional<ViewId> ViewFromCode(uint8_t code);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_VIEW_ID_H_
