// OpenOptions: what a user may say about how to open a volume (series, time point, spacing
// overrides) and the safety limits every reader enforces against lying headers.
//
// Thread safety: a plain value type.
#ifndef OCTOSCOPE_IO_OPEN_OPTIONS_H_
#define OCTOSCOPE_IO_OPEN_OPTIONS_H_

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>

#include "io/raw_layout.h"
#include "util/result.h"

namespace octoscope::io {

struct OpenOptions {
  int series = 0;  // Which image/series of a multi-series file.
  int time = 0;    // Which time point.
  // Overrides the file's spacing per axis where set (micrometres).
  std::array<std::optional<double>, 3> spacing_um;
  // Refuses files whose single xy plane of one channel would exceed this (a lying header must not
  // size an allocation).
  uint64_t max_plane_bytes = uint64_t{4} << 30;
  // Parses an Octoscope JSON raw sidecar. Set by app/ (protocol/ owns JSON); when unset, JSON
  // sidecars are reported as unsupported.
  std::function<Result<RawLayout>(const std::filesystem::path& sidecar)> load_raw_sidecar;
  // Called by OpenVolume once per warning of the volume it opened (VolumeInfo::warnings: what
  // the reader had to guess or ignore), right after opening, so a command can show it before a
  // long read. Unset: the warnings are only in info().
  std::function<void(const std::string& warning)> on_warning;
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_OPEN_OPTIONS_H_
