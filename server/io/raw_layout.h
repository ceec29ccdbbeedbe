// RawLayout: how voxels lie in a headerless binary file ("raw"), as described by a sidecar
// (Octoscope's JSON sidecar, parsed in protocol/, or a Voreen .vvd). See docs/formats.md.
//
// Thread safety: a plain value type.
#ifndef OCTOSCOPE_IO_RAW_LAYOUT_H_
#define OCTOSCOPE_IO_RAW_LAYOUT_H_

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "volume/data_type.h"

namespace octoscope::io {

// Sidecar files larger than this are refused unread.
inline constexpr uint64_t kMaxRawSidecarBytes = uint64_t{1} << 20;

struct RawLayout {
  std::filesystem::path data_file;       // The raw file itself (absolute or sidecar-relative).
  std::array<int64_t, 3> size{0, 0, 0};  // x, y, z.
  int channels = 1;
  std::vector<std::string> channel_names;  // Empty or one per channel.
  volume::DataType dtype = volume::DataType::kUint16;
  bool big_endian = false;
  // true: c fastest (x0c0 x0c1 … x1c0 …); false: planar, one whole volume per channel.
  bool interleaved = false;
  uint64_t header_bytes = 0;  // Bytes to skip at the start of the file.
  std::array<std::optional<double>, 3> spacing_um;
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_RAW_LAYOUT_H_
